"""A running asbuilt agent in a child process, for scripts and notebooks that drive a cell."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from typing import Any, Dict, Optional


def toml_text(config: Dict[str, Any]) -> str:
    """An agent configuration as TOML: a dict of tables (dicts) of numbers, strings, booleans
    and lists of them."""

    def value(v: Any) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, (int, float)):
            return repr(v)
        if isinstance(v, str):
            return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(value(x) for x in v) + "]"
        if isinstance(v, dict):
            return "{ " + ", ".join(f"{k} = {value(x)}" for k, x in v.items()) + " }"
        raise TypeError(f"cannot write {type(v).__name__} {v!r} into an agent configuration")

    lines = []
    for table, keys in config.items():
        if not isinstance(keys, dict):
            raise TypeError(f"[{table}] must be a dict of keys, got {type(keys).__name__}")
        lines.append(f"[{table}]")
        lines += [f"{k} = {value(v)}" for k, v in keys.items()]
        lines.append("")
    return "\n".join(lines)


class Agent:
    """`asbuilt agent --config FILE` in a child process (this package's own command line).

    `config` is a dict of tables, written to `folder/agent.toml`; relative paths in it are
    relative to `folder`. The agent's log goes to `folder/agent.log`. Use it as a context
    manager: leaving stops the agent with SIGTERM (open stations get their reports, the
    recording is closed)."""

    def __init__(self, config: Dict[str, Any], folder: str):
        # The agent runs in `folder`: a relative folder would be taken twice.
        folder = os.path.abspath(os.fspath(folder))
        os.makedirs(folder, exist_ok=True)
        self.folder = folder
        self.config_path = os.path.join(folder, "agent.toml")
        self.log_path = os.path.join(folder, "agent.log")
        with open(self.config_path, "w", encoding="utf-8") as f:
            f.write(toml_text(config))
        self.process: Optional[subprocess.Popen] = None

    def start(self) -> "Agent":
        log = open(self.log_path, "wb")
        self.process = subprocess.Popen(
            [sys.executable, "-m", "asbuilt", "agent", "--config", self.config_path],
            stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, cwd=self.folder,
        )
        log.close()
        return self

    def log(self) -> str:
        with open(self.log_path, encoding="utf-8", errors="replace") as f:
            return f.read()

    def stop(self, timeout: float = 60.0) -> int:
        """Stops the agent (SIGTERM, then SIGKILL after `timeout` s); returns its exit code."""
        p = self.process
        if p is None:
            return 0
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
            try:
                p.wait(timeout)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        return p.returncode

    def __enter__(self) -> "Agent":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def alive(self) -> bool:
        return self.process is not None and self.process.poll() is None

    def wait_until_serving(self, timeout: float = 60.0) -> None:
        """Raises with the agent's log if it exits before `timeout`; returns after the agent's
        log says it serves (its services are up)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if not self.alive():
                raise RuntimeError(f"the agent stopped before it served; its log:\n{self.log()}")
            if "serving" in self.log():
                return
            time.sleep(0.05)
        raise RuntimeError(f"the agent did not serve within {timeout} s; its log:\n{self.log()}")
