"""The staged pipeline: running collect, fit, evaluate and report one at a time in one directory gives the
metrics of one ``run_experiment``, and an evaluation before training is refused with what to run."""

from __future__ import annotations

import json

import pytest
from conftest import TINY, compose_cfg

from rmpfusion.pipeline.collect import collect
from rmpfusion.pipeline.fit import NotTrainedError, fit
from rmpfusion.pipeline.run import evaluate_and_report, run_experiment, start
from rmpfusion.pipeline.validate import resolve_and_validate
from rmpfusion.studies.compare import compare


def _run_config(overrides=()):
    return resolve_and_validate(compose_cfg(["experiment=2d2level_unstructured", *TINY, *overrides]))


def test_stages_one_at_a_time_give_the_metrics_of_one_run(tmp_path):
    run = _run_config()
    whole = run_experiment(run, tmp_path / "whole", progress=False)

    staged_dir = tmp_path / "staged"
    collect(start(run, staged_dir, progress=False))  # rmpfusion-collect
    exp = start(run, staged_dir, progress=False)  # rmpfusion-train: a new process would rebuild all of this
    fit(exp, collect(exp))
    exp = start(run, staged_dir, progress=False)  # rmpfusion-evaluate
    splits = collect(exp)
    staged = evaluate_and_report(exp, splits, fit(exp, splits, require_trained=True), started=0.0)

    n, _worst, differ, one_sided = compare(whole, staged, rtol=0.0)
    assert n > 50 and not differ and not one_sided, (differ, one_sided)
    assert set(whole["learners"]) == {"rmp", "un", "un_large"}  # both kinds of learner went through every stage
    assert json.loads((staged_dir / "metrics.json").read_text())["learners"]["rmp"]["resumed_from"] == 3


def test_evaluating_before_training_says_what_to_run(tmp_path):
    exp = start(_run_config(), tmp_path, progress=False)
    with pytest.raises(
        NotTrainedError,
        match=r"no fully trained checkpoints for \['rmp', 'un', 'un_large'\].*"
        r"run rmpfusion-train with the same overrides",
    ):
        fit(exp, collect(exp), require_trained=True)
    assert not (tmp_path / "checkpoints").exists()  # nothing was trained


def test_compare_holds_residuals_to_an_absolute_tolerance_and_everything_else_to_a_relative_one():
    """A residual that is zero in exact arithmetic (3.41e-9 vs 3.47e-9: rounding, 1.7 % apart) is equal; one that
    moved by 1e-3 is not; an ordinary number 1e-6 apart relatively is not equal at rtol 1e-9."""
    a = {"rmp": {"certificate": {"max_energy_identity_error": 3.41e-9}, "online_loss": 1.0}}
    b = {"rmp": {"certificate": {"max_energy_identity_error": 3.47e-9}, "online_loss": 1.0}}
    assert compare(a, b, rtol=1e-9)[2] == []
    b["rmp"]["certificate"]["max_energy_identity_error"] = 1e-3
    b["rmp"]["online_loss"] = 1.0 + 1e-6
    differ = compare(a, b, rtol=1e-9)[2]
    assert len(differ) == 2 and "a residual" in differ[0] and "online_loss" in differ[1], differ


def test_unit_weights_and_a_test_split_of_its_own_sampler(tmp_path):
    """eval.unit_weights rolls out the expert's tree with every weight 1 from the test starts, and what it reports
    is that tree's rollout, recomputed here; env.test_sampling moves only the test split's starts (train and
    validation are those of the run without it)."""
    import torch

    from rmpfusion.envs.demonstrations import load_dataset
    from rmpfusion.evaluate.metrics import rollout_rates
    from rmpfusion.pipeline.construct import build_tree, expert_spec, make_env

    hard = ["eval.unit_weights=true", "+env.test_sampling={start_speed: [2.0, 3.0]}"]
    run = _run_config(["experiment=2d1level", *hard])
    m = run_experiment(run, tmp_path / "hard", progress=False)
    plain = run_experiment(
        _run_config(["experiment=2d1level", "eval.unit_weights=true"]), tmp_path / "plain", progress=False
    )
    assert m["data"]["train"]["sha256"] == plain["data"]["train"]["sha256"]
    assert m["data"]["val"]["sha256"] == plain["data"]["val"]["sha256"]
    assert m["data"]["test"]["sha256"] != plain["data"]["test"]["sha256"]
    q0, qd0, aux = load_dataset(m["data"]["test"]["path"]).initial_states()
    speeds = qd0.norm(dim=-1)
    assert speeds.min() >= 2.0 - 1e-12 and speeds.max() <= 3.0 + 1e-12  # drawn from test_sampling's range

    env = make_env(run)
    unit = {name: {"type": "constant", "value": 1.0} for name in run.expert}
    tree = build_tree(expert_spec(run.model_copy(update={"expert": unit})), aux_dims=env.aux_dims())
    exp = start(run, tmp_path / "hard", progress=False)
    with torch.no_grad():
        ro = env.rollout(tree, q0, qd0, aux, horizon=exp.horizon, record_every=exp.fine_interval)
    expected = rollout_rates(ro)
    for key in ("success", "collision", "lyapunov_monotone_fraction"):
        assert m["unit_weights"][key] == pytest.approx(expected[key]), key
    assert {"online_loss", "online_loss_median", "online_loss_before_collision"} <= set(m["unit_weights"])
