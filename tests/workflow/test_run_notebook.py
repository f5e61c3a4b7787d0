"""The notebook runner (workflow/scripts/run_notebook.py) as a rule calls it: a failure's first line is its cause;
a run renders its plots inline in the HTML (the inline backend, nothing forcing Agg) without tqdm warnings."""
from __future__ import annotations

import json
import os
import re
import stat
import subprocess
import sys
from pathlib import Path

import pytest

#: Every test runs a notebook in a kernel (seconds): out of `make test-fast`.
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
RUNNER = ROOT / "workflow" / "scripts" / "run_notebook.py"

HEADER = """# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---
"""


def run(tmp_path: Path, name: str, cells: list[str], parameters: dict) -> tuple[subprocess.CompletedProcess, Path, Path]:
    """Run a percent-format notebook made of ``cells`` (the first is the parameters cell) through the runner."""
    source = tmp_path / f"{name}.py"
    body = [HEADER, "# %% tags=[\"parameters\"]\n" + cells[0]] + [f"# %%\n{cell}" for cell in cells[1:]]
    source.write_text("\n".join(body))
    executed, html = tmp_path / "logs" / f"{name}.ipynb", tmp_path / "html" / f"{name}.html"
    env = {key: value for key, value in os.environ.items() if key != "MPLBACKEND"}  # as the rules run it now
    env["PYTHONPATH"] = str(ROOT / "src") + os.pathsep + env.get("PYTHONPATH", "")
    env["PYTHONWARNINGS"] = "default"
    process = subprocess.run(
        [sys.executable, str(RUNNER), str(source), str(executed), str(html), json.dumps(parameters)],
        capture_output=True, text=True, env=env, cwd=tmp_path, timeout=300,
        preexec_fn=lambda: os.umask(0o022),
    )
    return process, executed, html


def test_a_failed_cell_prints_its_one_line_cause_first_then_the_notebook(tmp_path):
    cells = [
        "key = 'sky.n_images'\n",
        "print('\\x1b[31mcoloured noise\\x1b[0m')\n",
        "from sdm.errors import SDMInputError\n"
        "raise SDMInputError(f\"config key '{key}': n_sample = 128 is larger than the number of images (57)\")\n",
    ]
    process, executed, html = run(tmp_path, "stage", cells, {"key": "sky.n_images"})
    assert process.returncode == 1
    lines = process.stderr.splitlines()
    assert lines[0] == (f"{tmp_path / 'stage.py'} failed: SDMInputError: config key 'sky.n_images': "
                        "n_sample = 128 is larger than the number of images (57)")
    # cell [4]: papermill inserts the injected-parameters cell after the parameters cell
    assert lines[1] == f"(in cell [4]; the executed notebook, with the traceback, is {executed})"
    assert process.stdout == ""
    assert "\x1b" not in process.stderr
    assert executed.is_file() and not html.exists()


def test_a_notebook_that_cannot_be_read_names_it_first(tmp_path):
    process = subprocess.run(
        [sys.executable, str(RUNNER), str(tmp_path / "missing.py"), str(tmp_path / "m.ipynb"), str(tmp_path / "m.html"), "{}"],
        capture_output=True, text=True, timeout=120,
    )
    assert process.returncode == 1
    assert re.match(rf"{re.escape(str(tmp_path / 'missing.py'))} failed: \w+Error: ", process.stderr.splitlines()[0])


@pytest.fixture(scope="module")
def plotting_run(tmp_path_factory):
    """One run of a notebook that draws as the stage notebooks do and builds configurations with a progress bar."""
    tmp_path = tmp_path_factory.mktemp("plots")
    cells = [
        "out = 'fig.png'\n",
        "import matplotlib.pyplot as plt\n"
        "from sdm.experiments.data import build_sky_dataset, synthetic_images\n"
        "from sdm.experiments.report import figures\n"
        "configurations = build_sky_dataset(synthetic_images(4, seed=0), n_sample=3, progress=True)\n",
        # a pyplot figure shown with plt.show(), as the data / sky / tune notebooks do
        "fig, ax = plt.subplots()\nax.plot([0, 1], [0, 1])\nplt.show()\n",
        # a report figure saved and shown, then closed
        "figures.show_figure(figures.figure1(configurations[0]), out)\n"
        "assert plt.get_fignums() == []\n",
    ]
    process, executed, html = run(tmp_path, "plots", cells, {"out": str(tmp_path / "fig.png")})
    assert process.returncode == 0, process.stderr
    return tmp_path, executed, html


def test_plots_render_inline_in_the_html(plotting_run):
    tmp_path, executed, html = plotting_run
    notebook = json.loads(executed.read_text())
    images = [
        output for cell in notebook["cells"] if cell["cell_type"] == "code"
        for output in cell.get("outputs", []) if "image/png" in output.get("data", {})
    ]
    assert len(images) == 2
    assert html.read_text().count("data:image/png;base64") >= 2
    assert (tmp_path / "fig.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert stat.S_IMODE(html.stat().st_mode) == 0o644


def test_the_page_is_titled_by_its_job(plotting_run):
    """The rendered page's title is the job's name (the HTML file's), not nbconvert's default "Notebook"."""
    _, _, html = plotting_run
    assert f"<title>{html.stem}</title>" in html.read_text()




def test_the_page_shows_the_values_the_job_ran_with_in_the_parameters_cell(tmp_path):
    """The page's parameters cell shows each default replaced by the job's value, its comment kept; a value without a
    default is added; papermill's injected cell is left out of the page, not out of the executed notebook."""
    import nbformat

    page = _runner_module().page
    cells = ["sky = 'results/sky/sky.bin'  # input: the Sky set\nlevel = 0  # the noise level\nruns = 2\n",
             "print(sky, level, runs, threads)\n"]
    process, executed, html = run(tmp_path, "noise_level3", cells, {"sky": "data/sky.bin", "level": 3, "threads": 1})
    assert process.returncode == 0, process.stderr
    notebook = nbformat.read(executed, as_version=4)
    tags = [cell.metadata.get("tags", []) for cell in notebook.cells]
    assert ["injected-parameters"] in tags  # the job's record keeps papermill's cell
    shown = page(notebook)
    assert [cell.metadata.get("tags", []) for cell in shown.cells] == [tag for tag in tags
                                                                       if tag != ["injected-parameters"]]
    assert shown.cells[0].source.splitlines() == [
        "sky = \"data/sky.bin\"  # input: the Sky set", "level = 3  # the noise level", "runs = 2",
        "threads = 1  # this job's value (no default in the notebook)"]
    assert "data/sky.bin 3 2 1" in shown.cells[1].outputs[0]["text"]
    text = html.read_text()
    assert "celltag_parameters" in text and "celltag_injected-parameters" not in text
    assert "this job&#39;s value" in text or "this job's value" in text


def test_progress_bars_do_not_warn_in_a_notebook(plotting_run):
    _, executed, _ = plotting_run
    text = executed.read_text()
    assert "TqdmWarning" not in text and "IProgress" not in text


# -- kernel start-up failures ------------------------------------------------------------------------------


def _runner_module():
    sys.path.insert(0, str(RUNNER.parent))
    try:
        import run_notebook
    finally:
        sys.path.remove(str(RUNNER.parent))
    return run_notebook


class FlakyStart:
    """An execute_notebook stand-in whose first ``failures`` calls fail as a kernel that lost a port race."""

    def __init__(self, failures: int, error: Exception = RuntimeError("Kernel died before replying to kernel_info")):
        self.failures, self.error, self.calls = failures, error, []

    def __call__(self, *args, **kwargs):
        self.calls.append((args, kwargs))
        if len(self.calls) <= self.failures:
            raise self.error
        return "executed"


def test_a_kernel_that_fails_to_start_is_started_again(capsys):
    runner = _runner_module()
    execute = FlakyStart(failures=runner.KERNEL_STARTS - 1)
    assert runner.execute_with_kernel_restarts(execute, "notebook", parameters={"a": 1}) == "executed"
    assert len(execute.calls) == runner.KERNEL_STARTS
    assert all(call == (("notebook",), {"parameters": {"a": 1}}) for call in execute.calls)
    assert capsys.readouterr().err.count("the kernel failed to start") == runner.KERNEL_STARTS - 1


def test_kernel_start_failures_give_up_after_kernel_starts():
    runner = _runner_module()
    execute = FlakyStart(failures=runner.KERNEL_STARTS)
    with pytest.raises(RuntimeError, match="Kernel died before replying to kernel_info"):
        runner.execute_with_kernel_restarts(execute, "notebook")
    assert len(execute.calls) == runner.KERNEL_STARTS


@pytest.mark.parametrize("error", [RuntimeError("Kernel died"),
                                   ValueError("Kernel died before replying to kernel_info")])
def test_other_errors_are_not_retried(error):
    """A kernel that died while running cells (nbclient's DeadKernelError says "Kernel died"), or any error
    that is not a start-up failure, may have run cells already: it is raised at once."""
    runner = _runner_module()
    execute = FlakyStart(failures=1, error=error)
    with pytest.raises(type(error)):
        runner.execute_with_kernel_restarts(execute, "notebook")
    assert len(execute.calls) == 1


@pytest.mark.parametrize("signal_name", ["SIGTERM", "SIGHUP"])
def test_a_terminated_job_leaves_no_temporary_notebook(tmp_path, signal_name):
    """On main a job stopped by a signal (Snakemake and clusters send SIGTERM) left its hidden .tmp.ipynb."""
    import signal
    import time

    source = tmp_path / "slow.py"
    source.write_text("\n".join([HEADER, '# %% tags=["parameters"]\nx = 1', "# %%\nimport time\ntime.sleep(120)"]))
    executed, html = tmp_path / "logs" / "slow.ipynb", tmp_path / "html" / "slow.html"
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src") + os.pathsep + os.environ.get("PYTHONPATH", ""))
    process = subprocess.Popen([sys.executable, str(RUNNER), str(source), str(executed), str(html), "{}"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, cwd=tmp_path)
    deadline = time.monotonic() + 120
    while not list(executed.parent.glob(".slow.*.tmp.ipynb")) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert list(executed.parent.glob(".slow.*.tmp.ipynb")), "the runner never started the notebook"
    time.sleep(2)  # the kernel is in the sleeping cell
    process.send_signal(getattr(signal, signal_name))
    process.communicate(timeout=120)
    assert process.returncode != 0
    assert [path.name for path in executed.parent.iterdir()] == []


def test_a_temporary_notebook_left_by_a_killed_run_is_removed_by_the_next(tmp_path):
    """A run killed outright (SIGKILL) cannot clean up; the job's next run removes what it left."""
    executed = tmp_path / "logs" / "stage.ipynb"
    executed.parent.mkdir()
    left = executed.parent / ".stage.0123456789ab.tmp.ipynb"
    other = executed.parent / ".other.0123456789ab.tmp.ipynb"
    left.write_text("{")
    other.write_text("{")
    runner = _runner_module()
    assert runner.remove_stale_temporaries(executed) == [left]
    assert not left.exists() and other.exists()


def test_the_log_ends_with_the_cpu_seconds_of_the_runner_and_its_kernel(tmp_path):
    """The kernel spends 2 s of CPU in a cell: the log's last line (run_notebook.CPU_LINE) counts them with the
    runner's own, so it says more than 2 s; the runner's process alone spends about 1 s."""
    module = _runner_module()
    source = tmp_path / "burn.py"
    source.write_text("\n".join([HEADER, "# %% tags=[\"parameters\"]\nseconds = 2.0\n",
                                 "# %%\nimport time\nstart = time.process_time()\n"
                                 "while time.process_time() - start < seconds:\n    pass\nprint('burnt')\n"]))
    executed, html, log = tmp_path / "burn.ipynb", tmp_path / "burn.html", tmp_path / "logs" / "burn.log"
    env = {key: value for key, value in os.environ.items() if key != "MPLBACKEND"}
    env["PYTHONPATH"] = str(ROOT / "src") + os.pathsep + env.get("PYTHONPATH", "")
    script = (f"import sys; sys.path.insert(0, {str(RUNNER.parent)!r}); import run_notebook; "
              f"sys.exit(run_notebook.main({str(source)!r}, {str(executed)!r}, {str(html)!r}, '{{}}', {str(log)!r}))")
    process = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, cwd=tmp_path,
                             timeout=300)
    assert process.returncode == 0, process.stderr
    last = log.read_text().splitlines()[-1]
    found = re.match(module.CPU_LINE, last)
    assert found, last
    assert float(found.group(1)) > 2.0
