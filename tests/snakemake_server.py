"""Starts Snakemake runs for the tests (``snakemakes`` in tests/workflow/test_workflow.py) without paying its import each time.

``python -m snakemake`` spends about 1.5 s of CPU importing Snakemake, most of a dry run. This process imports
it once, then forks one child per run: the child is what ``python -m snakemake ARGS`` started in that
directory would be (working directory, umask 022, the caller's environment, ``sys.path[0]`` the working
directory as ``python -m`` sets it, stdin from /dev/null, stdout and stderr to the given files), runs
Snakemake's ``main()`` and exits through the interpreter's normal shutdown with Snakemake's exit status.

Protocol, one JSON object a line. On stdin: ``{"cwd", "args", "env", "stdout", "stderr"}`` starts a run.
On stdout: ``{"started": pid}`` for each request, in order, and ``{"pid": pid, "returncode": code}`` when a
run ends (a negative code: killed by that signal, as subprocess reports it); ``{"kill": pid}`` kills a run
that has not ended. At the end of stdin the runs still going are killed and the server exits.
"""
from __future__ import annotations

import json
import os
import selectors
import signal
import sys

import snakemake.api  # noqa: F401  (what main() imports next: also paid once)
import snakemake.cli


def _report(message: dict) -> None:
    os.write(1, (json.dumps(message) + "\n").encode())


def serve() -> dict:
    """Answer requests until stdin ends (then exit); return a request only in the forked child that runs it."""
    wakeup_read, wakeup_write = os.pipe()
    os.set_blocking(wakeup_write, False)
    signal.signal(signal.SIGCHLD, lambda *_: None)
    signal.set_wakeup_fd(wakeup_write)
    selector = selectors.DefaultSelector()
    selector.register(0, selectors.EVENT_READ)
    selector.register(wakeup_read, selectors.EVENT_READ)
    running, pending = set(), b""
    while True:
        for key, _ in selector.select():
            if key.fd == wakeup_read:
                os.read(wakeup_read, 4096)
                while running:
                    pid, status = os.waitpid(-1, os.WNOHANG)
                    if pid == 0:
                        break
                    running.discard(pid)
                    _report({"pid": pid, "returncode": os.waitstatus_to_exitcode(status)})
                continue
            chunk = os.read(0, 65536)
            if not chunk:  # the caller is gone: so are its runs
                for pid in running:
                    os.kill(pid, signal.SIGKILL)
                sys.exit(0)
            pending += chunk
            while b"\n" in pending:
                line, pending = pending.split(b"\n", 1)
                request = json.loads(line)
                if "kill" in request:
                    if request["kill"] in running:  # not yet reaped: the pid is still that run's
                        os.kill(request["kill"], signal.SIGKILL)
                    continue
                pid = os.fork()
                if pid == 0:
                    signal.set_wakeup_fd(-1)
                    signal.signal(signal.SIGCHLD, signal.SIG_DFL)
                    selector.close()
                    os.close(wakeup_read)
                    os.close(wakeup_write)
                    return request
                running.add(pid)
                _report({"started": pid})


def run(request: dict) -> None:
    os.chdir(request["cwd"])
    os.umask(0o022)
    for fd, path in ((0, os.devnull), (1, request["stdout"]), (2, request["stderr"])):
        opened = os.open(path, os.O_RDONLY if fd == 0 else os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        os.dup2(opened, fd)
        os.close(opened)
    os.environ.clear()
    os.environ.update(request["env"])
    sys.path[0] = os.getcwd()
    sys.argv = [os.path.join(os.path.dirname(snakemake.cli.__file__), "__main__.py"), *request["args"]]
    snakemake.cli.main()  # exits (SystemExit) with Snakemake's status


def warm_up() -> None:
    """What every run's ``main()`` does first and the same in each: building the argument parser imports the
    plugins and fills their registries (about 0.25 s of CPU a run), done once here before any fork."""
    snakemake.cli.get_argument_parser()


if __name__ == "__main__":
    warm_up()
    run(serve())
