"""``device``: where trees, learners, training and the 2D environment compute. On a machine without the device the
run config names it and the fix before anything runs; the evaluation path creates no tensor on another device
(checked on the meta device, here on any machine); on a machine with CUDA, trees, training and a tiny run agree with
the CPU (skipped elsewhere, never failing for lack of a GPU)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
import torch
from conftest import compose_cfg
from pydantic import ValidationError
from trees import TWO_LEVEL, grouping_tree_spec, two_level_inputs

import rmpfusion
from rmpfusion.assembly.errors import ConfigError
from rmpfusion.core.passes import evaluate
from rmpfusion.envs.common import OnDevice, on_device
from rmpfusion.envs.protocol import ComputesOn
from rmpfusion.pipeline.config import RunConfig
from rmpfusion.pipeline.validate import resolve_and_validate

cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device on this machine")
no_cuda = pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has a CUDA device")


def test_device_cpu_is_accepted():
    assert resolve_and_validate(compose_cfg(["device=cpu"])).device == "cpu"


@no_cuda
def test_a_device_this_machine_lacks_is_a_config_error_naming_it_and_the_fix():
    why = "this torch has no CUDA build" if torch.version.cuda is None else "no CUDA GPU is visible"
    for device in ("cuda", "cuda:1"):
        with pytest.raises(ConfigError) as err:
            resolve_and_validate(compose_cfg([f"device={device}"]))
        assert [str(i) for i in err.value.issues] == [
            f"device: '{device}' is not available here ({why}); set device=cpu, or run where a GPU is"
        ]


def test_an_unknown_device_is_reported_with_the_other_problems():
    with pytest.raises(ConfigError) as err:
        resolve_and_validate(compose_cfg(["device=mps", "expert.goal.type=rfb"]))
    paths = [i.path for i in err.value.issues]
    assert "device" in paths and "expert.goal.type" in paths


def test_run_config_itself_takes_cpu_and_cuda_devices_only():
    tree = {"root": {"dim": 2}, "nodes": {"a": {"parent": "q", "rmp": {"type": "damper"}}}}
    for device in ("cpu", "cuda", "cuda:3"):
        assert (
            RunConfig.model_validate({"env": {"type": "particle2d"}, "tree": tree, "device": device}).device == device
        )
    with pytest.raises(ValidationError, match="device"):
        RunConfig.model_validate({"env": {"type": "particle2d"}, "tree": tree, "device": "tpu"})


@no_cuda
def test_validate_cli_prints_the_message(tmp_path):
    env = {**os.environ, "WANDB_MODE": "disabled", "HYDRA_FULL_ERROR": "0"}
    r = subprocess.run(
        [sys.executable, "-m", "rmpfusion.cli.validate", "device=cuda", f"hydra.run.dir={tmp_path}"],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=str(tmp_path),
        env=env,
    )
    assert r.returncode == 2, r.stderr
    assert "device: 'cuda' is not available here" in r.stderr


@pytest.mark.parametrize("which", ["grouping", "franka"])
def test_the_evaluation_creates_no_tensor_off_the_trees_device(which):
    """On the meta device (shapes only) any tensor made elsewhere meets a meta tensor and fails: the path that runs
    on a GPU is the one checked here."""
    from manipulators import franka_tree_spec

    spec = grouping_tree_spec(1) if which == "grouping" else franka_tree_spec(n_obstacles=2)
    tree = rmpfusion.build_tree(spec).to("meta")
    q, qd = torch.empty(5, tree.dim, device="meta"), torch.empty(5, tree.dim, device="meta")
    aux = {k: torch.empty(5, d, device="meta") for k, d in tree.aux_dims.items()}
    for lean in (False, True):
        root = evaluate(tree.plan, q, qd, aux, lean=lean).root
        assert root.f.device.type == "meta" and root.M.shape == (5, tree.dim, tree.dim)


def test_environments_compute_on_a_chosen_device_and_return_cpu_records():
    from manipulators import franka_env

    from rmpfusion.envs import Particle2D

    for env in (Particle2D(n_obstacles=1), franka_env()):
        assert isinstance(env, ComputesOn) and env.to("cpu") is env
    tree = rmpfusion.build_tree(TWO_LEVEL)
    _q, _qd, _aux = two_level_inputs(3, torch.Generator().manual_seed(0))
    assert on_device(tree, "cpu") is tree and isinstance(on_device(tree, "meta"), OnDevice)


@cuda
def test_a_tree_on_cuda_equals_it_on_the_cpu():
    tree = rmpfusion.build_tree(grouping_tree_spec(2))
    gpu = rmpfusion.build_tree(grouping_tree_spec(2)).to("cuda")
    gpu.load_state_dict(tree.state_dict())
    g = torch.Generator().manual_seed(0)
    q, qd = torch.rand(8, 3, generator=g), torch.randn(8, 3, generator=g)
    aux = {k: 3 * torch.rand(8, 3, generator=g) - 1.5 for k in ("goal", "c", "c1", "c2", "c3")}
    out = gpu(q.cuda(), qd.cuda(), {k: v.cuda() for k, v in aux.items()})
    torch.testing.assert_close(out.qdd.cpu(), tree(q, qd, aux).qdd, rtol=1e-10, atol=1e-10)


@cuda
@pytest.mark.slow
def test_a_tiny_run_on_cuda_matches_the_cpu(tmp_path):
    import json

    metrics = {}
    for device in ("cpu", "cuda"):
        r = subprocess.run(
            [
                sys.executable,
                "-m",
                "rmpfusion.cli.run",
                "experiment=2d1level",
                "data=tiny",
                "train=tiny",
                "eval=fast",
                "eval.figures=false",
                "logger=disabled",
                f"device={device}",
                f"hydra.run.dir={tmp_path / device}",
            ],
            capture_output=True,
            text=True,
            timeout=900,
        )
        assert r.returncode == 0, r.stderr[-3000:]
        metrics[device] = json.loads((tmp_path / device / "metrics.json").read_text())
    a, b = metrics["cpu"]["learners"]["rmp"]["final"], metrics["cuda"]["learners"]["rmp"]["final"]
    for k in ("batch_loss", "online_loss", "success", "collision"):
        assert a[k] == pytest.approx(b[k], rel=1e-6, abs=1e-9), k
