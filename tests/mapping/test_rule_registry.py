"""Gradient rules as objects: a new rule with a compiled form is one Rule registered in one place, and the layer
and the trainer both take it; the rule modules import each other in one direction only."""
from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest
import torch

import sdm
from scenes import configuration_set
from sdm import RULES, Rule, SpatialDomainMapping, TrainSettings, train
from sdm.experiments import noisy_targets
from sdm.mapping import KernelFlow, dynamic_flow, native
from sdm.mapping.rules import by_zoom, closing, window_rule

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def toy():
    """A rule defined here, with an existing compiled form (the centred window over the 3x3 closing at zoom 0,
    eq. 19 above it: closed_centred_r1's arithmetic under another name), registered for the test only."""
    rule = RULES.register(Rule.by_zoom("toy_centred", window_rule(prepare=closing(3), centred=True), 1,
                                       KernelFlow.CENTRED))
    yield rule
    RULES.unregister("toy_centred")


@pytest.fixture
def compiled_calls(monkeypatch):
    """The calls of the compiled trainer (so a test knows a whole run was compiled)."""
    calls = []
    original = native.train_program
    monkeypatch.setattr(native, "train_program", lambda *args, **kwargs: calls.append(1) or original(*args, **kwargs))
    return calls


@pytest.mark.skipif(not native.enabled(), reason="no C compiler: the compiled kernel is not built")
def test_a_registered_rule_trains_compiled_and_the_layer_uses_it(toy, compiled_calls):
    """A rule is added by defining and registering it (here, in this file): sdm.train runs it by name on the compiled
    kernel, with the torch path's theta history to the bit, and the layer takes it by name."""
    assert SpatialDomainMapping(rule="toy_centred").rule is toy
    assert SpatialDomainMapping(rule="toy_centred").flow_rule is toy.flow
    data = configuration_set(48, seed=21)
    noisy = data.with_targets(noisy_targets(data.targets, 2, 5))
    settings = TrainSettings(lr=3e-4, s=3, seed=2, rule="toy_centred")
    compiled = train(noisy, settings, progress=False)
    assert compiled_calls == [1]
    with native.disabled():
        reference = train(noisy, settings, progress=False)
    assert compiled_calls == [1]  # the torch path
    assert torch.equal(compiled.theta, reference.theta)
    assert not torch.equal(compiled.theta[0], compiled.theta[-1])  # it trained
    # the same arithmetic as the registered closed_centred_r1, and not the paper's rule
    assert torch.equal(compiled.theta, train(noisy, TrainSettings(lr=3e-4, s=3, seed=2, rule="closed_centred_r1"),
                                             progress=False).theta)
    paper = train(noisy, TrainSettings(lr=3e-4, s=3, seed=2), progress=False)
    assert not torch.equal(compiled.theta, paper.theta)


def test_train_takes_a_rule_object_or_a_bare_function(compiled_calls):
    """TrainSettings.rule takes a Rule (registered or not) or a bare flow function; a function has no compiled
    form, so it trains on the torch path, with the same theta as its Rule."""
    data = configuration_set(32, seed=22)
    unregistered = Rule.by_zoom("unregistered", window_rule(prepare=closing(3)), 1)
    assert "unregistered" not in RULES and unregistered.kernel_flows([1, 0]) is None
    by_rule = train(data, TrainSettings(s=2, seed=1, rule=unregistered), progress=False)
    bare = by_zoom(window_rule(prepare=closing(3)), dynamic_flow, 1)
    by_function = train(data, TrainSettings(s=2, seed=1, rule=bare), progress=False)
    assert compiled_calls == []
    assert torch.equal(by_rule.theta, by_function.theta)
    assert not torch.equal(by_rule.theta[0], by_rule.theta[-1])


def _modules() -> list[str]:
    package = ROOT / "src" / "sdm"
    return sorted(".".join(("sdm", *path.relative_to(package).with_suffix("").parts)).removesuffix(".__init__")
                  for path in package.rglob("*.py"))


@pytest.mark.slow
def test_every_module_imports_first_on_its_own():
    """Each module of the library imported first, with no sdm module loaded before it (one interpreter, sdm's
    modules dropped between imports; torch stays loaded): no import cycle breaks any entry point."""
    modules = _modules()
    assert {"sdm.mapping.rules", "sdm.mapping.research_rules", "sdm.mapping.native"} <= set(modules)
    script = ("import importlib, sys, torch\n"
              "failed = []\n"
              "for name in sys.argv[1:]:\n"
              "    for loaded in [m for m in sys.modules if m == 'sdm' or m.startswith('sdm.')]:\n"
              "        del sys.modules[loaded]\n"
              "    try:\n"
              "        importlib.import_module(name)\n"
              "    except Exception as error:\n"
              "        failed.append(f'{name}: {error!r}')\n"
              "print(failed)\n")
    done = subprocess.run([sys.executable, "-c", script, *modules], capture_output=True, text=True, timeout=600)
    assert done.stdout.strip() == "[]", done.stdout + done.stderr[-3000:]


def test_the_rule_modules_do_not_import_each_other_both_ways():
    """rules.py never imports the experiments, not even inside a function: research_rules.py registers them in it."""
    tree = ast.parse((ROOT / "src" / "sdm" / "mapping" / "rules.py").read_text())
    imported = {node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)}
    imported |= {alias.name for node in ast.walk(tree) if isinstance(node, ast.Import) for alias in node.names}
    assert "crossing" in imported and not any("research_rules" in name for name in imported), imported
    assert sdm.RULES is RULES
