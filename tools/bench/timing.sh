# Sourced by the bench scripts that time whole processes.
#
# timed LOG CMD...: runs CMD with its output into LOG and prints its wall and CPU seconds (user +
# system, all its threads).
timed() {
    python3 -c 'import resource, subprocess, sys, time
t = time.monotonic()
with open(sys.argv[1], "w") as log:
    subprocess.run(sys.argv[2:], stdout=log, stderr=log, check=True)
r = resource.getrusage(resource.RUSAGE_CHILDREN)
print(time.monotonic() - t, r.ru_utime + r.ru_stime)' "$@"
}

# median X...: the median of the numbers (the lower middle of an even count).
median() { printf '%s\n' "$@" | sort -n | awk '{a[NR]=$1} END {print a[int((NR+1)/2)]}'; }
