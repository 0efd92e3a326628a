//! `fuzz`: mutation fuzzing of every input asbuilt reads (see `asbuilt_tests::fuzz`).
//!
//! ```text
//! cargo build --release -p asbuilt-tests --bins
//! target/release/fuzz --seconds 600                 # ten minutes over every target
//! target/release/fuzz --seconds 60 --target scan-laz --seed 7
//! target/release/fuzz --inputs 300                  # the fixed budget the tests run
//! ```
//!
//! Each target runs in a worker process (this binary again), so that an abort, a hang or an
//! allocation no input justifies is caught with the input that caused it. Failing inputs are
//! written to `--keep` (default `out/fuzz`); copy one into `tests/fuzz/regressions/<target>/`
//! and every later run checks it first.

use std::alloc::{GlobalAlloc, Layout, System};
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode, Stdio};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use asbuilt_tests::fuzz::{self, Outcome, TARGETS, Target};

/// Refuses (aborts with a message) any single allocation above the current limit, which the
/// worker sets from each input's size: a header that claims 10^12 points must be an error, not
/// an allocation.
struct Guard;

static LIMIT: AtomicUsize = AtomicUsize::new(usize::MAX);

fn check(size: usize) {
    if size > LIMIT.load(Ordering::Relaxed) {
        // No allocation here: format into a stack buffer.
        let mut buf = [0u8; 96];
        let head = b"fuzz: refused an allocation of ";
        buf[..head.len()].copy_from_slice(head);
        let mut n = head.len();
        let mut digits = [0u8; 20];
        let mut k = 0;
        let mut v = size;
        loop {
            digits[k] = b'0' + (v % 10) as u8;
            k += 1;
            v /= 10;
            if v == 0 {
                break;
            }
        }
        for d in digits[..k].iter().rev() {
            buf[n] = *d;
            n += 1;
        }
        let tail = b" bytes\n";
        buf[n..n + tail.len()].copy_from_slice(tail);
        n += tail.len();
        // SAFETY: writing a valid buffer to stderr, then ending the process.
        unsafe {
            libc::write(2, buf.as_ptr().cast(), n);
            libc::abort();
        }
    }
}

// SAFETY: forwards to the system allocator after a size check.
unsafe impl GlobalAlloc for Guard {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        check(layout.size());
        // SAFETY: the caller's contract for `layout` is the system allocator's.
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        check(layout.size());
        // SAFETY: the caller's contract for `layout` is the system allocator's.
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        check(new_size);
        // SAFETY: `ptr` came from this allocator, which is the system's; the caller's contract
        // holds for it.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` came from this allocator, which is the system's.
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: Guard = Guard;

/// The largest single allocation an input of `len` bytes justifies: working buffers, plus a
/// generous multiple of what the file could hold.
fn allocation_limit(len: usize) -> usize {
    (64 << 20) + 512 * len
}

struct Args {
    targets: Vec<&'static Target>,
    seconds: Option<f64>,
    inputs: u64,
    seed: u64,
    timeout: Duration,
    keep: PathBuf,
    regressions: PathBuf,
    worker: Option<Worker>,
    replay: Option<PathBuf>,
    emit: Vec<u64>,
    check_seeds: bool,
}

struct Worker {
    seeds: PathBuf,
    from: u64,
    to: u64,
    seconds: Option<f64>,
}

const USAGE: &str = "usage: fuzz [--seconds N | --inputs N] [--target NAME]... [--seed S] \
                     [--timeout SECONDS] [--keep DIR] [--regressions DIR]\n\
                     \x20      fuzz --target NAME --replay FILE      (one input, in this process)\n\
                     \x20      fuzz --target NAME --emit I [--seed S] (write input I to --keep)";

fn parse() -> Result<Args, String> {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let mut a = Args {
        targets: Vec::new(),
        seconds: None,
        inputs: 300,
        seed: 1,
        timeout: Duration::from_secs(5),
        keep: repo.join("out/fuzz"),
        regressions: repo.join("tests/fuzz/regressions"),
        worker: None,
        replay: None,
        emit: Vec::new(),
        check_seeds: false,
    };
    let mut seeds = None;
    let (mut from, mut to) = (0, u64::MAX);
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let mut value = || it.next().ok_or(format!("{flag} needs a value\n{USAGE}"));
        let number = |v: String| {
            v.parse::<f64>()
                .ok()
                .filter(|x| *x >= 0.0 && x.is_finite())
                .ok_or(format!("{flag} {v:?}: give a number\n{USAGE}"))
        };
        match flag.as_str() {
            "--target" => {
                let v = value()?;
                let names: Vec<_> = TARGETS.iter().map(|t| t.name).collect();
                a.targets.push(fuzz::target(&v).ok_or(format!(
                    "--target {v:?}: the targets are {}",
                    names.join(", ")
                ))?);
            }
            "--seconds" => a.seconds = Some(number(value()?)?),
            "--inputs" => a.inputs = number(value()?)? as u64,
            "--seed" => a.seed = number(value()?)? as u64,
            "--timeout" => a.timeout = Duration::from_secs_f64(number(value()?)?),
            "--keep" => a.keep = value()?.into(),
            "--regressions" => a.regressions = value()?.into(),
            "--worker-seeds" => seeds = Some(PathBuf::from(value()?)),
            "--from" => from = number(value()?)? as u64,
            "--to" => to = number(value()?)? as u64,
            "--replay" => a.replay = Some(value()?.into()),
            "--emit" => a.emit.push(number(value()?)? as u64),
            "--check-seeds" => a.check_seeds = true,
            "-h" | "--help" => return Err(USAGE.into()),
            _ => return Err(format!("unknown argument {flag:?}\n{USAGE}")),
        }
    }
    if a.targets.is_empty() {
        a.targets = TARGETS.iter().collect();
    }
    a.worker = seeds.map(|seeds| Worker {
        seeds,
        from,
        to,
        seconds: a.seconds,
    });
    Ok(a)
}

fn main() -> ExitCode {
    let args = match parse() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("{e}");
            return ExitCode::from(2);
        }
    };
    if let Some(w) = &args.worker {
        return work(args.targets[0], w, args.seed);
    }
    if let Some(file) = &args.replay {
        return replay(args.targets[0], file);
    }
    if args.check_seeds {
        return check_seeds(&args.targets);
    }
    if !args.emit.is_empty() {
        return match emit(&args) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => {
                eprintln!("fuzz: {e}");
                ExitCode::from(2)
            }
        };
    }
    match drive(&args) {
        Ok(0) => ExitCode::SUCCESS,
        Ok(n) => {
            eprintln!(
                "fuzz: {n} failing input(s) kept under {}",
                args.keep.display()
            );
            ExitCode::from(1)
        }
        Err(e) => {
            eprintln!("fuzz: {e}");
            ExitCode::from(2)
        }
    }
}

/// Runs one input in this process, reporting on stdout. Panics are caught here; aborts and
/// hangs are the parent's to see.
fn run_one(target: &Target, index: u64, name: &str, bytes: &[u8], scratch: &Path) {
    println!("start {index}");
    let _ = std::io::stdout().flush();
    LIMIT.store(allocation_limit(bytes.len()), Ordering::Relaxed);
    let outcome = std::panic::catch_unwind(|| target.run(name, bytes, scratch));
    LIMIT.store(usize::MAX, Ordering::Relaxed);
    let line = match outcome {
        Ok(Outcome::Read(_) | Outcome::Refused(_)) => format!("pass {index}"),
        Ok(Outcome::Unclear(e)) => format!("unclear {index} {}", one_line(&e)),
        Err(p) => {
            let msg = p
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_default();
            format!("panic {index} {} at {}", one_line(&msg), last_panic())
        }
    };
    println!("{line}");
    let _ = std::io::stdout().flush();
    for e in std::fs::read_dir(scratch).into_iter().flatten().flatten() {
        let p = e.path();
        let _ = if p.is_dir() {
            std::fs::remove_dir_all(&p)
        } else {
            std::fs::remove_file(&p)
        };
    }
}

static PANIC_AT: std::sync::Mutex<String> = std::sync::Mutex::new(String::new());

fn last_panic() -> String {
    PANIC_AT.lock().map(|s| s.clone()).unwrap_or_default()
}

fn quiet_panics() {
    std::panic::set_hook(Box::new(|info| {
        if let (Ok(mut s), Some(l)) = (PANIC_AT.lock(), info.location()) {
            *s = l.to_string();
        }
    }));
}

fn one_line(s: &str) -> String {
    let s = s.replace('\n', " | ");
    s.chars().take(400).collect()
}

fn work(target: &Target, w: &Worker, seed: u64) -> ExitCode {
    quiet_panics();
    let seeds = match fuzz::load_seeds(&w.seeds, target) {
        Ok(s) if !s.is_empty() => s,
        Ok(_) => {
            eprintln!("no seeds for {}", target.name);
            return ExitCode::from(2);
        }
        Err(e) => {
            eprintln!("seeds of {}: {e}", target.name);
            return ExitCode::from(2);
        }
    };
    let scratch = tempfile::tempdir().expect("a scratch folder");
    let start = Instant::now();
    for i in w.from..w.to {
        if w.seconds
            .is_some_and(|s| start.elapsed().as_secs_f64() >= s)
        {
            break;
        }
        let (name, bytes) = fuzz::input(target, &seeds, seed, i);
        run_one(target, i, &name, &bytes, scratch.path());
    }
    ExitCode::SUCCESS
}

fn replay(target: &Target, file: &Path) -> ExitCode {
    quiet_panics();
    let Ok(bytes) = std::fs::read(file) else {
        eprintln!("cannot read {}", file.display());
        return ExitCode::from(2);
    };
    // Kept inputs are named `<index>-<seed name>`: the reader needs the seed's extension.
    let stored = file.file_name().unwrap().to_string_lossy().into_owned();
    let name = stored.split_once('-').map_or(stored.as_str(), |(_, n)| n);
    let scratch = tempfile::tempdir().expect("a scratch folder");
    run_one(target, 0, name, &bytes, scratch.path());
    ExitCode::SUCCESS
}

/// Every seed, unmutated, must be read by its target: a seed that is refused would leave the
/// target's reading code unfuzzed.
fn check_seeds(targets: &[&'static Target]) -> ExitCode {
    let seeds = tempfile::tempdir().expect("a seed folder");
    if let Err(e) = fuzz::write_seeds(seeds.path(), &asbuilt_tests::shared_data()) {
        eprintln!("fuzz: cannot write the seed files: {e:#}");
        return ExitCode::from(2);
    }
    let scratch = tempfile::tempdir().expect("a scratch folder");
    let mut bad = 0;
    for target in targets {
        let list = fuzz::load_seeds(seeds.path(), target).unwrap_or_default();
        for (name, bytes) in &list {
            match target.run(name, bytes, scratch.path()) {
                Outcome::Read(what) => eprintln!("{} {name}: {what}", target.name),
                Outcome::Refused(e) if name.starts_with("bad-") => {
                    eprintln!("{} {name}: refused, as meant: {e}", target.name)
                }
                Outcome::Refused(e) | Outcome::Unclear(e) => {
                    bad += 1;
                    eprintln!("FAIL {} seed {name} is not read: {e}", target.name);
                }
            }
        }
        if list.is_empty() {
            bad += 1;
            eprintln!("FAIL {} has no seeds", target.name);
        }
    }
    if bad == 0 {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    }
}

/// Writes inputs `--emit` of each target to `--keep`, named as kept failures are.
fn emit(args: &Args) -> Result<(), String> {
    let seeds = tempfile::tempdir().map_err(|e| e.to_string())?;
    fuzz::write_seeds(seeds.path(), &asbuilt_tests::shared_data())
        .map_err(|e| format!("cannot write the seed files: {e:#}"))?;
    for target in &args.targets {
        let list = fuzz::load_seeds(seeds.path(), target).map_err(|e| e.to_string())?;
        let dir = args.keep.join(target.name);
        std::fs::create_dir_all(&dir).map_err(|e| e.to_string())?;
        for &i in &args.emit {
            let (name, bytes) = fuzz::input(target, &list, args.seed, i);
            let path = dir.join(format!("{i}-{name}"));
            std::fs::write(&path, bytes).map_err(|e| e.to_string())?;
            eprintln!("{}", path.display());
        }
    }
    Ok(())
}

/// What went wrong with one input.
struct Failure {
    target: &'static str,
    index: u64,
    what: String,
}

/// Replays every kept regression input of every target, each in a worker of its own.
fn replay_regressions(args: &Args, me: &std::path::Path, failures: &mut Vec<Failure>) {
    for target in &args.targets {
        let dir = args.regressions.join(target.name);
        let Ok(entries) = std::fs::read_dir(&dir) else {
            continue;
        };
        let mut files: Vec<PathBuf> = entries.flatten().map(|e| e.path()).collect();
        files.sort();
        for f in &files {
            let mut cmd = Command::new(me);
            cmd.args(["--target", target.name, "--replay"]).arg(f);
            let mut kept = Vec::new();
            supervise(cmd, args.timeout, target, &mut |i, what| {
                kept.push((i, what))
            });
            for (_, what) in kept {
                failures.push(Failure {
                    target: target.name,
                    index: 0,
                    what: format!("regression {}: {what}", f.display()),
                });
            }
        }
        eprintln!(
            "{}: {} regression input(s) checked",
            target.name,
            files.len()
        );
    }
}

/// Runs the regressions, then every target's budget; returns the number of failures.
fn drive(args: &Args) -> Result<usize, String> {
    let seeds = tempfile::tempdir().map_err(|e| e.to_string())?;
    fuzz::write_seeds(seeds.path(), &asbuilt_tests::shared_data())
        .map_err(|e| format!("cannot write the seed files: {e:#}"))?;
    let me = std::env::current_exe().map_err(|e| e.to_string())?;
    let mut failures = Vec::new();

    replay_regressions(args, &me, &mut failures);

    let total_weight: f64 = args.targets.iter().map(|t| t.weight).sum();
    for target in &args.targets {
        let started = Instant::now();
        let budget = args.seconds.map(|s| s * target.weight / total_weight);
        let inputs = (args.inputs as f64 * target.weight).ceil() as u64;
        let mut next = 0u64;
        let mut ran = 0u64;
        let before = failures.len();
        loop {
            let left = budget.map(|b| b - started.elapsed().as_secs_f64());
            if left.is_some_and(|l| l <= 0.0) || (budget.is_none() && next >= inputs) {
                break;
            }
            let mut cmd = Command::new(&me);
            cmd.args(["--target", target.name, "--worker-seeds"])
                .arg(seeds.path())
                .args(["--seed", &args.seed.to_string()])
                .args(["--from", &next.to_string()]);
            match left {
                Some(l) => cmd.args(["--seconds", &format!("{l:.3}")]),
                None => cmd.args(["--to", &inputs.to_string()]),
            };
            let finished = supervise(cmd, args.timeout, target, &mut |i, what| {
                failures.push(Failure {
                    target: target.name,
                    index: i,
                    what,
                })
            });
            match finished {
                Ended::Done(n) => {
                    ran += n;
                    break;
                }
                // Go on after the input that killed the worker.
                Ended::Died(n, at) => {
                    ran += n;
                    next = at + 1;
                }
            }
        }
        eprintln!(
            "{}: {ran} inputs in {:.1} s, {} failure(s)",
            target.name,
            started.elapsed().as_secs_f64(),
            failures.len() - before
        );
    }

    if !failures.is_empty() {
        std::fs::create_dir_all(&args.keep).map_err(|e| e.to_string())?;
        for f in &failures {
            let target = fuzz::target(f.target).expect("a known target");
            let list = fuzz::load_seeds(seeds.path(), target).map_err(|e| e.to_string())?;
            let (name, bytes) = fuzz::input(target, &list, args.seed, f.index);
            let dir = args.keep.join(f.target);
            std::fs::create_dir_all(&dir).map_err(|e| e.to_string())?;
            let path = dir.join(format!("{}-{name}", f.index));
            if !f.what.starts_with("regression") {
                std::fs::write(&path, bytes).map_err(|e| e.to_string())?;
            }
            eprintln!(
                "FAIL {} input {} ({}): {}",
                f.target,
                f.index,
                path.display(),
                f.what
            );
        }
    }
    Ok(failures.len())
}

enum Ended {
    /// The worker went through its inputs (how many ran).
    Done(u64),
    /// The worker died or hung on an input (how many ran, which one).
    Died(u64, u64),
}

/// Runs a worker, reporting each failing input to `fail`.
fn supervise(
    mut cmd: Command,
    timeout: Duration,
    target: &Target,
    fail: &mut dyn FnMut(u64, String),
) -> Ended {
    let err_path = std::env::temp_dir().join(format!(
        "asbuilt-fuzz-{}-{}.stderr",
        target.name,
        std::process::id()
    ));
    let err_file = std::fs::File::create(&err_path).expect("a stderr file");
    let mut child = cmd
        .stdout(Stdio::piped())
        .stderr(err_file)
        .spawn()
        .expect("the fuzz worker starts");
    let stdout = child.stdout.take().expect("piped");
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines() {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    let mut current = None;
    let mut ran = 0;
    loop {
        match rx.recv_timeout(timeout) {
            Ok(Ok(line)) => {
                let mut parts = line.splitn(3, ' ');
                let (kind, index) = (parts.next().unwrap_or(""), parts.next().unwrap_or(""));
                let index: u64 = index.parse().unwrap_or(0);
                let rest = parts.next().unwrap_or("").to_string();
                match kind {
                    "start" => current = Some(index),
                    "pass" => {
                        current = None;
                        ran += 1;
                    }
                    "unclear" => {
                        current = None;
                        ran += 1;
                        fail(
                            index,
                            format!("an error that does not name the file: {rest}"),
                        );
                    }
                    "panic" => {
                        current = None;
                        ran += 1;
                        fail(index, format!("panic: {rest}"));
                    }
                    _ => {}
                }
            }
            Ok(Err(_)) | Err(mpsc::RecvTimeoutError::Disconnected) => {
                let status = child.wait().expect("the worker is waited for");
                let stderr = std::fs::read_to_string(&err_path).unwrap_or_default();
                let _ = std::fs::remove_file(&err_path);
                return match current {
                    Some(i) => {
                        let tail: Vec<&str> = stderr.lines().rev().take(3).collect();
                        fail(
                            i,
                            format!("the process ended ({status}): {}", tail.join(" | ")),
                        );
                        Ended::Died(ran, i)
                    }
                    None => Ended::Done(ran),
                };
            }
            Err(mpsc::RecvTimeoutError::Timeout) => {
                let _ = child.kill();
                let _ = child.wait();
                let _ = std::fs::remove_file(&err_path);
                return match current {
                    Some(i) => {
                        fail(
                            i,
                            format!("no result within {:.0} s", timeout.as_secs_f64()),
                        );
                        Ended::Died(ran, i)
                    }
                    // Between inputs: nothing hung, the worker was slow to start.
                    None => Ended::Done(ran),
                };
            }
        }
    }
}
