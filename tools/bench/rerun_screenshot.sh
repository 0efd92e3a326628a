#!/usr/bin/env bash
# Screenshots of what a remote reviewer sees: the demo's demo.rrd (or the .rrd given) served by
# `rerun --serve-web` and opened in headless Chromium, software-rendered.
# Installs rerun-sdk (PyPI), Debian's chromium and puppeteer-core (npm): run by hand, never in CI.
#
#   tools/bench/rerun_screenshot.sh [FILE.rrd] [OUT_DIR]
#
# Writes OUT_DIR/part.png (the opening view) and OUT_DIR/history.png (the layer history tab);
# without FILE.rrd it runs the demo (DEMO_ARGS, e.g. "--closed-loop") and also writes
# OUT_DIR/report.png, the demo's whole report.html.
set -euo pipefail
cd "$(dirname "$0")/../.."
out=${2:-out/screenshot}
mkdir -p "$out"

command -v rerun >/dev/null || pip install "rerun-sdk==0.36.*"
command -v chromium >/dev/null || { apt-get update -q && DEBIAN_FRONTEND=noninteractive apt-get install -y -q chromium; }
(cd tools/screenshot && [ -d node_modules ] || npm install --silent)

rrd=${1:-}
report=
if [ -z "$rrd" ]; then
  cargo build --release -p asbuilt-tools
  # shellcheck disable=SC2086 # DEMO_ARGS are words on purpose
  target/release/asbuilt demo ${DEMO_ARGS:-} --out "$out/demo" >/dev/null
  rrd="$out/demo/demo.rrd"
  report="$(realpath "$out/demo/report.html")"
fi

# Ports of this run's own. `rerun` is a Python launcher whose server is a child process: it
# starts in a process group of its own (setsid), and the script stops that group by the
# launcher's PID when it ends, never another process that matches a pattern.
grpc=$((20000 + $$ % 10000)); web=$((grpc + 1))
setsid rerun --serve-web "$rrd" --port "$grpc" --web-viewer-port "$web" >"$out/rerun.log" 2>&1 &
server=$!
trap 'kill -- "-$server" 2>/dev/null || true; wait "$server" 2>/dev/null || true' EXIT
sleep 5
url="http://127.0.0.1:$web/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A$grpc%2Fproxy"
node tools/screenshot/shoot.mjs "$url" "$out" "${WAIT:-60}" "${HISTORY_TAB:-119,40}" $report
echo "screenshots in $out"
