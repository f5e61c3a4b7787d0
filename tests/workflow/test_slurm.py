"""The ``.test`` workflow on a real single-node SLURM cluster, through ``profiles/slurm``.

The test starts the cluster itself: ``munged`` with its own key and socket, then ``slurmctld`` and
``slurmd`` from a ``slurm.conf`` it writes (one node, localhost, this machine's CPUs and memory, no
accounting database). The configuration goes to ``/etc/slurm/slurm.conf``, SLURM's default place,
written only where none is and removed afterwards: the SLURM executor's job step starts each job with
``srun`` after removing every ``SLURM_*`` variable from its environment, ``SLURM_CONF`` too, so a
configuration found only through ``$SLURM_CONF`` is lost inside the job (``srun: fatal: Could not
establish a configuration source``). The daemons run in the foreground as this process's children and
are stopped by PID, after the cluster's jobs are cancelled, also when a test fails.

One run with an impossible depth shift fails inside a SLURM job, and the stage's one-line cause must
reach Snakemake's own output; with the value fixed the run completes. Its tables must equal the local
run's (``completed_run`` of tests/workflow/test_workflow.py) byte for byte but the measured seconds, every
non-local job must be a SLURM job that completed, and ``snakemake -n`` must find nothing to do.

Behind the marker ``slurm``, off by default (``make test-slurm`` runs it; it needs root, ``slurm-wlm``
and ``munge``, and skips naming what is missing). On a busy 2-core machine it took 33 minutes: the local
run 13, the two SLURM runs 18 (47 jobs submitted).
"""
from __future__ import annotations

import csv
import gzip
import importlib.util
import io
import json
import os
import re
import shutil
import socket
import subprocess
import tempfile
import time
from pathlib import Path

import pytest

from test_workflow import ROOT, _merge, completed_run, dot_test_config, snakemake, workdir  # noqa: F401
from sdm.io import CHECKSUM_SUFFIX, csv_damage

pytestmark = pytest.mark.slurm

SLURM_CONF = Path("/etc/slurm/slurm.conf")
#: The first line of the configuration this test writes: what it may overwrite or remove, and nothing else.
OURS = "# written by the sdm test tests/workflow/test_slurm.py for its own one-node cluster; removed when it ends"
TOOLS = ("munged", "slurmctld", "slurmd", "sbatch", "srun", "squeue", "scancel", "sinfo")
#: The test's only departure from the profile: status checks every few seconds instead of every 40 s and
#: more (a real cluster's scheduler would not thank us), and squeue, as there is no accounting database.
POLLING = ("--slurm-status-command", "squeue", "--slurm-init-seconds-before-status-checks", "2",
           "--seconds-between-status-checks", "2")
#: A c* that no data set allows (every point moved behind the camera), where .test has 0.5: the schema
#: and the config check accept any finite number, only the depth stage knows the nearest point.
BAD_C, GOOD_C = -1000.0, 0.5


def _tool(name: str) -> str | None:
    return shutil.which(name, path=os.pathsep.join([os.environ.get("PATH", ""), "/usr/sbin", "/sbin"]))


def _why_not() -> str | None:
    """Why this machine cannot host the test cluster, or None."""
    missing = [name for name in TOOLS if _tool(name) is None]
    if missing:
        return f"SLURM/MUNGE not installed (missing {', '.join(missing)}): apt-get install slurm-wlm munge"
    if os.geteuid() != 0:
        return "needs root: the test cluster runs slurmctld and slurmd as root (SlurmUser=root)"
    if importlib.util.find_spec("snakemake_executor_plugin_slurm") is None:
        return "snakemake-executor-plugin-slurm is not installed (the workflow extra)"
    if SLURM_CONF.exists() and not SLURM_CONF.read_text(errors="replace").startswith(OURS):
        return f"{SLURM_CONF} exists and was not written by this test: this machine has its own SLURM configuration"
    return None


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _memory_mb() -> int:
    with open("/proc/meminfo") as meminfo:
        kib = next(int(line.split()[1]) for line in meminfo if line.startswith("MemTotal:"))
    return kib // 1024 * 9 // 10  # slurmd drains a node whose RealMemory exceeds what it finds


def slurm_conf(root: Path, socket_path: Path) -> str:
    ctld_port, slurmd_port = _free_port(), _free_port()
    return "\n".join([
        OURS,
        "ClusterName=sdmtest",
        "SlurmctldHost=localhost",
        "SlurmUser=root",
        "SlurmdUser=root",
        f"SlurmctldPort={ctld_port}",
        f"SlurmdPort={slurmd_port}",
        "AuthType=auth/munge",
        "CredType=cred/munge",
        f"AuthInfo=socket={socket_path}",
        f"StateSaveLocation={root}/state",
        f"SlurmdSpoolDir={root}/spool",
        f"SlurmctldPidFile={root}/slurmctld.pid",
        f"SlurmdPidFile={root}/slurmd.pid",
        f"SlurmctldLogFile={root}/slurmctld.log",
        f"SlurmdLogFile={root}/slurmd.log",
        "ProctrackType=proctrack/linuxproc",
        "TaskPlugin=task/none",
        "SelectType=select/cons_tres",
        "SelectTypeParameters=CR_Core_Memory",
        "AccountingStorageType=accounting_storage/none",
        "JobAcctGatherType=jobacct_gather/none",
        "JobCompType=jobcomp/none",
        "MpiDefault=none",
        "ReturnToService=2",
        "DefMemPerCPU=1000",  # a job that asks for no memory does not take the whole node's
        # Finished jobs stay in squeue for two hours: the plugin reads their state there, and so does the test.
        "MinJobAge=7200",
        f"NodeName=localhost CPUs={os.cpu_count()} RealMemory={_memory_mb()} State=UNKNOWN",
        "PartitionName=debug Nodes=localhost Default=YES MaxTime=INFINITE State=UP",
        "",
    ])


def _slurm(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([_tool(args[0]), *args[1:]], capture_output=True, text=True, timeout=60)


class Cluster:
    """The daemons this test started (``subprocess.Popen``, in the foreground) and their folder."""

    def __init__(self, root: Path):
        self.root = root
        self.daemons: dict[str, subprocess.Popen] = {}

    def start(self, name: str, *args: str) -> None:
        output = open(self.root / f"{name}.out", "wb")
        self.daemons[name] = subprocess.Popen([_tool(name), *args], stdout=output, stderr=subprocess.STDOUT,
                                              stdin=subprocess.DEVNULL)
        output.close()

    def wait_until_idle(self, seconds: float = 60) -> None:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            for name, process in self.daemons.items():
                if process.poll() is not None:
                    raise RuntimeError(f"{name} exited with {process.returncode}:\n{self.logs()}")
            state = _slurm("sinfo", "--noheader", "--format=%T").stdout.strip()
            if state == "idle":
                return
            time.sleep(0.5)
        raise RuntimeError(f"the node is not idle after {seconds} s (sinfo: {state!r}):\n{self.logs()}")

    def logs(self) -> str:
        return "\n".join(f"--- {path.name}\n{path.read_text(errors='replace')[-2000:]}"
                         for path in sorted(self.root.glob("*.out")) + sorted(self.root.glob("*.log")))

    def stop(self) -> None:
        """Cancel every job of the cluster and wait for them, then stop the daemons by PID, newest first."""
        if "slurmctld" in self.daemons and self.daemons["slurmctld"].poll() is None:
            _slurm("scancel", "--full", "--user", "root")
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline and _slurm("squeue", "--noheader", "--states=R,CG,PD").stdout.strip():
                time.sleep(0.5)
        for process in reversed(list(self.daemons.values())):
            if process.poll() is None:
                process.terminate()
                try:
                    process.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    process.kill()
                    process.wait(timeout=30)


@pytest.fixture(scope="module")
def cluster():
    """A one-node SLURM cluster on this machine, up for the module's tests; everything stopped afterwards."""
    reason = _why_not()
    if reason:
        pytest.skip(reason)
    # Not under pytest's 0700 base folder: munged refuses a socket in a folder others cannot enter.
    root = Path(tempfile.mkdtemp(prefix="sdm-slurm-"))
    root.chmod(0o711)
    keys = root / "key"
    keys.mkdir(mode=0o700)
    for folder in ("state", "spool"):
        (root / folder).mkdir()
    key = keys / "munge.key"
    key.write_bytes(os.urandom(1024))
    key.chmod(0o400)
    socket_path = root / "munge.socket"
    running = Cluster(root)
    try:
        running.start("munged", "--foreground", f"--key-file={key}", f"--socket={socket_path}",
                      f"--pid-file={root}/munged.pid", f"--log-file={root}/munged.log", f"--seed-file={keys}/seed")
        for _ in range(100):
            if socket_path.exists() or running.daemons["munged"].poll() is not None:
                break
            time.sleep(0.1)
        SLURM_CONF.parent.mkdir(parents=True, exist_ok=True)
        SLURM_CONF.write_text(slurm_conf(root, socket_path))
        running.start("slurmctld", "-D", "-f", str(SLURM_CONF))
        running.start("slurmd", "-D", "-f", str(SLURM_CONF), "-N", "localhost")
        running.wait_until_idle()
        yield running
    finally:
        running.stop()
        if SLURM_CONF.exists() and SLURM_CONF.read_text(errors="replace").startswith(OURS):
            SLURM_CONF.unlink()
        shutil.rmtree(root, ignore_errors=True)


def test_a_job_step_finds_the_configuration_without_slurm_conf(cluster, tmp_path):
    """What the plugin's job step does: ``srun`` inside a batch job, without SLURM_CONF (it removes it)."""
    out = tmp_path / "job.out"
    result = _slurm("sbatch", "--wait", "--mem=100", f"--output={out}", "--wrap",
                    "env -u SLURM_CONF srun -n1 echo job step ran")
    assert result.returncode == 0, result.stdout + result.stderr + out.read_text()
    assert out.read_text().strip() == "job step ran"


def slurm_snakemake(directory: Path, *args: str) -> subprocess.CompletedProcess:
    """Snakemake through profiles/slurm in ``directory``, polling the test cluster every few seconds."""
    return snakemake("--workflow-profile", str(ROOT / "profiles" / "slurm"), *POLLING, *args,
                     cwd=directory, timeout=3600)


def _depth_config(c: float) -> dict:
    config = dot_test_config()
    shifts = config["research"]["depth"]["shifts_c"]
    assert GOOD_C in shifts
    return _merge(config, {"research": {"depth": {"shifts_c": [c if value == GOOD_C else value for value in shifts]}}})


@pytest.fixture(scope="module")
def slurm_run(cluster, tmp_path_factory):
    """The .test workflow through profiles/slurm: first with c* = BAD_C (fails inside a SLURM job), then fixed.

    Returns the working directory, both runs' results and the wall time of the two; SDM_CACHE_DIR is a
    fresh folder, so that the native kernel compiled there shows that the variable reached the jobs.
    """
    directory = tmp_path_factory.mktemp("slurm_run")
    cache = tmp_path_factory.mktemp("slurm_cache")
    started = time.monotonic()
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("SDM_CACHE_DIR", str(cache))
        patch.delenv("SLURM_CONF", raising=False)
        failed = slurm_snakemake(workdir(directory, _depth_config(BAD_C)))
        fixed = slurm_snakemake(workdir(directory, _depth_config(GOOD_C)))
    seconds = time.monotonic() - started
    return {"directory": directory, "cache": cache, "failed": failed, "fixed": fixed, "seconds": seconds}


def _output(result: subprocess.CompletedProcess) -> str:
    return result.stdout + result.stderr


def test_a_stage_failing_on_the_cluster_shows_its_cause_and_the_fixed_run_completes(slurm_run):
    failed, fixed = slurm_run["failed"], slurm_run["fixed"]
    output = _output(failed)
    assert failed.returncode != 0, output[-3000:]
    assert re.search(r"has been submitted with SLURM jobid", output), output[-3000:]
    causes = [line for line in output.splitlines() if " failed: " in line]
    wanted = f"SDMInputError: config key 'research.depth.shifts_c': c = {BAD_C!r} m moves the nearest point"
    assert causes and re.search(r"notebooks/\w+\.py failed: ", causes[0]) and wanted in causes[0], output[-3000:]
    # Snakemake itself only says the SLURM job failed: the cause comes from the stage's log, at the end
    assert output[output.index("The failed stages' causes:"):].splitlines()[1] == causes[0]
    print("the failure as the user sees it:", causes[0], sep="\n")
    assert '"cell_type"' not in output  # no notebook JSON on the console
    assert fixed.returncode == 0, _output(fixed)[-5000:]


def _jobs(output: str) -> list[tuple[str, str, bool]]:
    """Snakemake's jobs in a run's output: (rule, jobid, ran locally)."""
    return [(match["rule"], match["jobid"], bool(match["local"])) for match in re.finditer(
        r"^(?P<local>local)?rule (?P<rule>\w+):\n(?:    .*\n)*?    jobid: (?P<jobid>\d+)$", output, re.MULTILINE)]


def _submitted(output: str) -> dict[str, str]:
    """Snakemake jobid -> SLURM job id, from the plugin's "Job N has been submitted with SLURM jobid M"."""
    return dict(re.findall(r"^Job (\d+) has been submitted with SLURM jobid (\d+)", output, re.MULTILINE))


def declared_local_rules() -> set[str]:
    """The rules the Snakefile's ``localrules:`` block names (they run on the submitting node)."""
    block = re.search(r"^localrules:\n((?:[ \t]+\w+,?\n)+)", (ROOT / "Snakefile").read_text(), re.MULTILINE)
    assert block, "the Snakefile has no localrules: block"
    return set(re.findall(r"\w+", block[1]))


def test_every_job_but_the_local_rules_ran_as_a_completed_slurm_job(slurm_run):
    output = _output(slurm_run["fixed"])
    jobs, submitted = _jobs(output), _submitted(output)
    remote = [(rule, jobid) for rule, jobid, local in jobs if not local]
    assert remote and len(submitted) == len(remote), output[-3000:]
    assert {jobid for _, jobid in remote} == set(submitted)
    local = {rule for rule, _, is_local in jobs if is_local}
    assert local and local <= declared_local_rules(), local
    # squeue keeps finished jobs (MinJobAge): each submission is a job that ran to COMPLETED, for its rule
    records = {}
    for line in _slurm("squeue", "--noheader", "--states=all", "--format=%i|%T|%k").stdout.splitlines():
        slurm_id, state, comment = line.split("|", 2)
        records[slurm_id] = (state, comment)
    for rule, jobid in remote:
        state, comment = records[submitted[jobid]]
        assert state == "COMPLETED" and (comment == f"rule_{rule}" or comment.startswith(f"rule_{rule}_wildcards_")), \
            (rule, jobid, state, comment)
    # the run before the fix: the SLURM jobs that failed are the bad c*'s depth jobs, and only those
    failed = {records[slurm_id][1] for slurm_id in _submitted(_output(slurm_run["failed"])).values()
              if records[slurm_id][0] == "FAILED"}
    assert failed and all(comment.startswith(f"rule_depth_runs_wildcards_{BAD_C!r}_") for comment in failed), failed
    # the jobs ran with the submitting shell's environment: the native kernel was compiled into SDM_CACHE_DIR
    assert list(slurm_run["cache"].glob("sdm_native_*.so")), sorted(slurm_run["cache"].iterdir())
    print(f"SLURM runs: {slurm_run['seconds']:.0f} s, {len(submitted)} + "
          f"{len(_submitted(_output(slurm_run['failed'])))} jobs submitted (fixed run + failed run)")


def test_nothing_is_left_to_do_after_the_slurm_run(slurm_run):
    result = snakemake("-n", cwd=slurm_run["directory"])
    assert "Nothing to be done" in _output(result), _output(result)


#: The measured seconds in the tables: columns with these headers (CSV, gzip-compressed CSV, Markdown and
#: LaTeX), Table 3's summary line of times per run, Table 7's line of training times, and the CPU-time ratios
#: Tables 6 and 7's summaries quote ("at 1/27 of its CPU time", "at 180x SDM's CPU time"). Everything else is
#: computed from the seeds and must match to the byte.
TIMED_COLUMNS = {"seconds", "cpu_s", "train_cpu_s", "seconds_per_run", "s / run", "cpu_ms", "CPU ms / config",
                 "train_s", "training CPU s", "pays_off", "cheaper than CMA-ES from (configs)"}
#: The measured seconds in the verdict's facts (``table*_verdict.json``): keys of CPU-time ratios and of counts
#: computed from them.
TIMED_KEYS = {"cpu_ratio", "search_cpu_ratio", "pays_off_configs"}
TIMED_LINE = ("- time per run ", "- **Training CPU time**")  # Table 3's and Table 4's lines, Table 7's
TIMED_PHRASES = re.compile(r"from [0-9]+ configurations|at [0-9.]+ ms|[0-9]+x less time|"
                           r"(?:at )?(?:1/)?[0-9][0-9.]*x? (?:of )?(?:its |[\w-]+'s )?CPU time")


HTML_CELL = re.compile(r"<t[hd][^>]*>(.*?)</t[hd]>", re.DOTALL)


def _cells(path: Path) -> list[list[str]]:
    """A table's cells as written (CSV, gzip-compressed CSV, Markdown ``|`` or LaTeX ``&`` rows, HTML ``<tr>``
    rows: the text around the cells first), each row a list of strings."""
    compressed = path.name.endswith(".csv.gz")
    text = gzip.decompress(path.read_bytes()).decode() if compressed else path.read_text()
    text = TIMED_PHRASES.sub("(time)", text)
    if path.suffix == ".csv" or compressed:
        return list(csv.reader(io.StringIO(text)))
    if path.suffix == ".html":
        return [[HTML_CELL.sub("", row), *HTML_CELL.findall(row)] for row in text.split("<tr")]
    separator = "|" if path.suffix == ".md" else "&"
    return [line.split(separator) for line in text.splitlines()]


def _header(cell: str) -> str:
    """A header cell without its padding and a LaTeX row end."""
    return cell.strip().removesuffix("\\\\").strip()


def _without_timed_keys(value):
    """A JSON value without the TIMED_KEYS, at any depth."""
    if isinstance(value, dict):
        return {key: _without_timed_keys(item) for key, item in value.items() if key not in TIMED_KEYS}
    if isinstance(value, list):
        return [_without_timed_keys(item) for item in value]
    return value


def without_measured_seconds(path: Path) -> list[list[str]] | dict:
    """A table's cells without its measured seconds (the TIMED_COLUMNS, header and values, and TIMED_LINE); a
    JSON file's data without its TIMED_KEYS."""
    if path.suffix == ".json":
        return _without_timed_keys(json.loads(path.read_text()))
    rows = [row for row in _cells(path) if not row[0].startswith(TIMED_LINE)]
    header = next((row for row in rows if any(_header(cell) in TIMED_COLUMNS for cell in row)), None)
    if header is None:
        return rows
    timed = {index for index, cell in enumerate(header) if _header(cell) in TIMED_COLUMNS}
    return [[cell for index, cell in enumerate(row) if index not in timed] if len(row) == len(header) else row
            for row in rows]


def test_tables_equal_the_local_runs_but_the_measured_seconds(slurm_run, completed_run):
    ours, local = slurm_run["directory"] / "results" / "tables", completed_run / "results" / "tables"
    names = sorted(path.name for path in local.iterdir())
    assert names and sorted(path.name for path in ours.iterdir()) == names
    for name in names:  # a table without measured seconds is compared whole
        if (ours / name).read_bytes() == (local / name).read_bytes():
            continue
        if name.endswith(CHECKSUM_SUFFIX):  # a table's checksum: right for its own table, the same rows and name
            table = name.removesuffix(CHECKSUM_SUFFIX)
            assert csv_damage(ours / table) is None and csv_damage(local / table) is None, name
            assert (ours / name).read_text().split()[1:] == (local / name).read_text().split()[1:], name
        else:
            assert without_measured_seconds(ours / name) == without_measured_seconds(local / name), name
