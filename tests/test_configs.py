"""Every config in conf/ composes, validates and builds; bad configs fail with path-named errors before running."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import CONF, TINY, compose_cfg

from rmpfusion.assembly.errors import ConfigError
from rmpfusion.pipeline.construct import build_all
from rmpfusion.pipeline.validate import resolve_and_validate
from rmpfusion.registry import LEAF_RMPS

EXPERIMENTS = sorted(p.stem for p in (CONF / "experiment").glob("*.yaml"))

#: The map a leaf that reads a particular map's output (LeafRMP.coordinates) is tried under, on the 2-D root.
MAP_FOR_COORDINATES = {"moving_offset": "{type: moving_offset, origin: goal, velocity: [0.1, -0.2]}"}


def _overrides_for(group: str, option: str) -> list[str]:
    """How to select one file of a group so that the rest of the config fits it."""
    if group == "rmp":
        fixed = getattr(LEAF_RMPS.get(compose_cfg()["tree"]["nodes"]["conditioning"]["rmp"]["type"]).obj, "dim", None)
        import yaml

        leaf = LEAF_RMPS.get(yaml.safe_load((CONF / "rmp" / f"{option}.yaml").read_text())["type"]).obj
        one_d = getattr(leaf, "dim", None) == 1
        assert fixed is None
        node = "obstacle" if one_d else "conditioning"
        under = (
            [f"~tree.nodes.{node}.map", f"+tree.nodes.{node}.map={MAP_FOR_COORDINATES[leaf.coordinates]}"]
            if leaf.coordinates
            else []
        )
        return [f"rmp@tree.nodes.{node}.rmp={option}", *under]
    if group == "weights":
        return [f"weights@learners.rmp.weights={option}"]
    if group == "learner":
        return [f"+learner@learners.extra={option}"]
    if (group, option) in VARIANTS:
        return VARIANTS[group, option]
    for exp in EXPERIMENTS:  # env/tree/expert/data/train files belonging to an experiment are used with it
        text = (CONF / "experiment" / f"{exp}.yaml").read_text()
        if f"override /{group}: {option}\n" in text or f"/{group}@env.test_scene: {option}\n" in text:
            return [f"experiment={exp}"]
    if group == "robot":  # any robot: an experiment whose starts are drawn around the robot's own home
        return ["experiment=reach", f"robot={option}"]
    if group == "sim":  # any simulator: the Panda experiment in it
        return ["experiment=franka", f"sim={option}"]
    if group == "scene":  # any scene: the Panda experiment's goals with it
        return ["experiment=franka", f"scene={option}", f"scene@env.test_scene={option}"]
    return [f"{group}={option}"]


#: files that are an experiment's documented variants, used with it
VARIANTS = {
    ("tree", "lasa"): ["experiment=lasa", "lasa_variant=cloned", "tree=lasa"],  # LASA's weights-only baseline
    ("tree", "lasa_map"): ["experiment=lasa", "lasa_variant=cloned"],  # the tree LASA's cloned variant learns
    ("train", "bc_lasa"): ["experiment=lasa", "lasa_variant=cloned"],
    ("data", "recorded"): ["experiment=lasa", "data=recorded", "data.format=lasa", "data.shape=Angle"],
    ("train", "match_lasa"): ["experiment=lasa", "train=match_lasa"],  # trajectory matching in place of BC
    ("train", "apg"): ["experiment=2d2level", "train=apg", "eval=eager"],  # training without demonstrations
    ("train", "match_arm_recordings"): ["experiment=recorded_arm", "train=match_arm_recordings"],
    ("data", "panda_moved_cylinder"): ["experiment=recorded_arm", "data=panda_moved_cylinder"],
    ("data", "panda_moved_cylinder_blind"): ["experiment=recorded_arm", "data=panda_moved_cylinder_blind"],
    # the variant groups (conf/config.yaml: after experiment), each option with an experiment whose tree it fits
    ("learned_leaves", "2d1level"): ["experiment=2d1level", "learned_leaves=2d1level"],
    ("learned_leaves", "2d2level"): ["experiment=2d2level", "learned_leaves=2d2level"],
    ("learned_leaves", "arm_reach"): ["experiment=recorded_arm", "learned_leaves=arm_reach"],
    ("per_edge_aux", "2d1level"): ["experiment=2d1level", "per_edge_aux=2d1level"],
    ("per_edge_aux", "2d2level"): ["experiment=2d2level", "per_edge_aux=2d2level"],
    ("attractor_weight", "radial"): ["experiment=recorded_iiwa", "attractor_weight=radial"],
    ("attractor_weight", "constant"): ["experiment=recorded_arm", "attractor_weight=constant"],
    ("obstacle_weight", "constant"): ["experiment=recorded_arm", "obstacle_weight=constant"],
    ("weight_init", "unit"): ["experiment=franka", "weight_init=unit"],
    ("lasa_variant", "cloned"): ["experiment=lasa", "lasa_variant=cloned"],
}

#: the groups whose options vary an experiment (conf/config.yaml lists them after it, so they change its keys)
VARIANT_GROUPS = (
    "learned_leaves",
    "per_edge_aux",
    "attractor_weight",
    "obstacle_weight",
    "weight_init",
    "lasa_variant",
)


#: every file of a config group; conf/study/ holds studies, not run configs (tests/test_studies.py composes every run
#: of every study)
CONFIG_FILES = sorted(
    (p.parent.name, p.stem) for p in CONF.glob("*/*.yaml") if p.parent.name not in ("experiment", "study")
)


def test_every_group_file_is_listed():
    groups = {g for g, _ in CONFIG_FILES}
    assert {
        "env",
        "tree",
        "expert",
        "rmp",
        "weights",
        "learner",
        "train",
        "data",
        "logger",
        "sweep",
        "launcher",
        "sim",
    } <= groups


@pytest.mark.parametrize("group,option", CONFIG_FILES, ids=[f"{g}/{o}" for g, o in CONFIG_FILES])
def test_every_config_file_composes_validates_builds(group, option):
    cfg = compose_cfg(_overrides_for(group, option), hydra_cfg=group in ("sweep", "launcher"))
    run = resolve_and_validate(cfg)
    _env, expert, learners = build_all(run)
    assert expert.dim == run.tree.root.dim and learners
    if group == "sim":
        assert _env.params.sim.type == option and type(_env.checker().sim).__name__.lower().startswith(option)
    if group == "sweep":
        assert cfg.hydra.sweeper.params, "a sweep recipe must set hydra.sweeper.params"
    if group == "launcher":
        assert option.split("_")[0] in cfg.hydra.launcher._target_.lower()


def _defaults_of(experiment: str) -> list:
    import yaml

    return (yaml.safe_load((CONF / "experiment" / f"{experiment}.yaml").read_text()) or {}).get("defaults", [])


def _group_of(entry: str) -> str:
    """``override /learner@learners.un`` -> ``learner``; a bare name (``2d1level``) is an option of the file's own
    group, the experiment group."""
    entry = entry.removeprefix("override ").strip()
    return entry.lstrip("/").split("@")[0].split("/")[0] if entry.startswith("/") else "experiment"


@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_no_experiment_extends_another(experiment):
    """Experiments are flat: none names another in its defaults list; a variant of one is a config group option that
    composes with any experiment (conf/config.yaml: learned_leaves, per_edge_aux, attractor_weight, ...)."""
    for entry in _defaults_of(experiment):
        if isinstance(entry, str):
            assert entry == "_self_", f"conf/experiment/{experiment}.yaml extends experiment {entry!r}"
        else:
            for key, option in entry.items():
                assert _group_of(key) != "experiment", f"conf/experiment/{experiment}.yaml names {key}: {option}"


def test_the_extension_check_reads_every_way_to_name_another_experiment():
    assert [_group_of(e) for e in ("2d1level", "/experiment", "override /experiment", "/experiment@x")] == [
        "experiment"
    ] * 4
    assert _group_of("override /train") == "train" and _group_of("/learner@learners.un") == "learner"


def test_every_variant_group_is_chosen_after_the_experiment_and_every_option_is_composed_with_one():
    """The variant groups sit after ``experiment`` in conf/config.yaml's defaults (so their keys win over the
    experiment's) with no option chosen by default, and each option is composed above with an experiment it fits."""
    import yaml

    listed = yaml.safe_load((CONF / "config.yaml").read_text())["defaults"]
    chosen = dict(next(iter(e.items())) if isinstance(e, dict) else (e, None) for e in listed)
    order = list(chosen)
    assert all(order.index(g) > order.index("experiment") and chosen[g] is None for g in VARIANT_GROUPS)
    for group in VARIANT_GROUPS:
        options = {o for g, o in CONFIG_FILES if g == group}
        assert options and all((group, o) in VARIANTS for o in options), group


@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_every_experiment_validates_and_builds(experiment):
    run = resolve_and_validate(compose_cfg([f"experiment={experiment}"]))
    # named for the experiment; experiment=reach and its smoke preset add the robot (reach_panda), whatever it is
    robot = run.env.robot.name if experiment.startswith("reach") else None
    shape = run.data.shape if experiment == "lasa" else None  # experiment=lasa adds the shape (lasa_Angle)
    suffix = robot or shape
    assert run.name == (experiment if suffix is None else f"{experiment}_{suffix}")
    _env, expert, learners = build_all(run)
    assert set(learners) == set(run.learners)
    assert expert.describe().startswith(run.tree.root.name)


def test_without_an_experiment_the_run_is_named_default():
    """conf/config.yaml's own configuration is not labelled as one of the experiments."""
    assert resolve_and_validate(compose_cfg()).name == "default"
    assert (
        resolve_and_validate(compose_cfg(["tree=2d2level", "env=particle2d_2obstacles", "expert=2d2level"])).name
        == "default"
    )


@pytest.mark.parametrize(
    ("overrides", "name"),
    [
        (["data.shape=Sshape"], "lasa_Sshape"),
        (["data=recorded", "data.files=[demos.csv]"], "lasa_recorded"),  # the block lists shape: null
        (["data=tiny"], "lasa_expert"),  # an expert preset has no shape key at all
    ],
)
def test_the_lasa_experiment_is_named_for_its_shape_or_else_its_source(overrides, name):
    """A null shape is "no shape" (a run on the user's own files), never the text None in the run's name."""
    assert compose_cfg(["experiment=lasa", *overrides]).name == name


def test_sweep_job_directories_carry_the_jobs_overrides(tmp_path):
    """hydra.sweep.subdir is <job number>_<name>_<overrides>: readable, unique, and without the keys that change
    where or how a job runs and logs (conf/config.yaml's exclude_keys) or that the name already says."""
    r = _cli(
        "rmpfusion.cli.validate",
        "-m",
        "experiment=2d2level",
        "seed=0,1",
        "train.lr=3e-3",
        "logger=disabled",
        f"data.cache_dir={tmp_path / 'cache'}",
        f"hydra.sweep.dir={tmp_path / 'sweep'}",
    )
    assert r.returncode == 0, r.stderr[-3000:]
    said = [
        ln.split("run directory: ", 1)[1].split(" (", 1)[0]
        for ln in r.stdout.splitlines()
        if ln.startswith("run directory: ")
    ]
    jobs = sorted(Path(d).name for d in said)
    assert jobs == ["0_2d2level_seed=0,train.lr=0.003", "1_2d2level_seed=1,train.lr=0.003"]  # as the sweeper writes it
    assert not [p for p in (tmp_path / "sweep").iterdir() if p.is_dir()]  # validating left no job directory
    cfg = compose_cfg(
        [
            "experiment=2d1level",
            "seed=2",
            "name=mine",
            "logger.mode=online",
            "launcher=joblib",
            "sweep=seeds",
            "+data.cache_dir=/shared/cache",
            "train=tiny",
        ],
        hydra_cfg=True,
    )
    assert cfg.hydra.job.override_dirname == "seed=2,train=tiny"


def test_paper_sizes_are_the_defaults():
    run = resolve_and_validate(compose_cfg(["experiment=2d2level_unstructured"]))
    assert (run.train.optimizer, run.train.batch_size, run.train.iterations) == ("rmsprop", 200, 20000)
    assert (run.data.train_envs, run.data.train_trajectories, run.data.points) == (20, 50, 60)
    _, _, learners = build_all(run)
    ratio = learners["un_large"].num_parameters() / learners["rmp"].num_parameters()
    assert abs(ratio - 5.8) < 0.1 and abs(learners["un"].num_parameters() / learners["rmp"].num_parameters() - 1) < 0.05


# --------------------------------------------------------------------------- overrides reach the modules
def test_override_changes_built_rmp():
    base = build_all(resolve_and_validate(compose_cfg()))[1]
    changed = build_all(resolve_and_validate(compose_cfg(["tree.nodes.goal.rmp.gain=3.5"])))[1]
    assert base.rmps["goal"].gain == 1.0 and changed.rmps["goal"].gain == 3.5


def test_override_swaps_leaf_preset_and_weight_network():
    run = resolve_and_validate(
        compose_cfg(
            [
                "rmp@tree.nodes.goal.rmp=rmpflow_goal_attractor",
                "weights@learners.rmp.weights=mlp_small",
                "learners.rmp.weights.floor=0.01",
            ]
        )
    )
    _, expert, learners = build_all(run)
    assert type(expert.rmps["goal"]).__name__ == "RMPflowGoalAttractor"
    w = learners["rmp"].tree.weights["goal"].fn
    assert [layer.out_features for layer in w.layers] == [16, 16, 1] and w.floor == 0.01


def test_override_changes_expert_weight():
    _, expert, _ = build_all(resolve_and_validate(compose_cfg(["expert.obstacle.high=9"])))
    assert expert.weights["obstacle"].fn.high == 9.0


# --------------------------------------------------------------------------- the catalogue of bad configs
BAD = {
    "unknown_type": (["expert.goal.type=rfb"], "expert.goal.type", "did you mean 'rbf'"),
    "unknown_rmp_type": (["tree.nodes.goal.rmp.type=goal_atractor"], "tree.nodes.goal.rmp.type", "goal_attractor"),
    "type_not_a_name": (["tree.nodes.goal.map.type=[a]"], "tree.nodes.goal.map.type", "unknown task map"),
    "misspelt_key": (["+tree.nodes.goal.rmp.gian=2"], "tree.nodes.goal.rmp.gian", "did you mean 'gain'"),
    "misspelt_top_level": (["+trian.lr=1"], "trian", "did you mean 'train'"),
    "wrong_type": (["train.batch_size=lots"], "train.batch_size", "lots"),
    "wrong_param_type": (["tree.nodes.goal.rmp.gain=fast"], "tree.nodes.goal.rmp.gain", "fast"),
    "missing_parameter": (["~expert.goal.low"], "expert.goal.low", "missing"),
    "dimension_mismatch": (
        [
            "tree.nodes.goal.rmp.type=collision_avoidance",
            "~tree.nodes.goal.rmp.gain",
            "~tree.nodes.goal.rmp.w_u",
            "~tree.nodes.goal.rmp.w_l",
        ],
        "tree.nodes.goal.rmp",
        "dimension",
    ),
    "map_dimension_mismatch": (["tree.nodes.goal.map.origin=[1,2,3]"], "tree.nodes.goal.map", "dimension"),
    "cycle": (["tree.nodes.goal.parent=conditioning", "tree.nodes.conditioning.parent=goal"], "tree.nodes.", "cycle"),
    "orphan": (["tree.nodes.goal.parent=nowhere"], "tree.nodes.goal.parent", "not a node"),
    "duplicate_name": (["+tree.nodes.q={parent: q, rmp: {type: damper}}"], "tree.nodes.q", "root's name"),
    "unknown_aux": (["tree.nodes.goal.map.origin=gaol"], "tree.nodes.goal.map.origin", "did you mean 'goal'"),
    "unknown_aux_in_expert": (["expert.obstacle.center=obstacle2_center"], "expert.obstacle.center", "provides"),
    "non_positive_constant": (["~expert.goal", "+expert.goal={type: constant, value: 0}"], "expert.goal.value", "> 0"),
    "non_positive_shorthand": (["expert.goal=-1"], "expert.goal", "> 0"),
    "expert_unknown_node": (["+expert.gaol={type: constant}"], "expert.gaol", "did you mean 'goal'"),
    "leaf_without_rmp": (["~tree.nodes.goal.rmp"], "tree.nodes.goal.rmp", "leaf needs"),
    "unknown_learner": (["learners.rmp.type=rnp"], "learners.rmp.type", "did you mean 'rmp'"),
    "unknown_env": (["env.type=particle3d"], "env.type", "particle2d"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_config_is_rejected_with_its_path(case, monkeypatch):
    overrides, path, hint = BAD[case]
    import rmpfusion.pipeline.run as pipeline

    monkeypatch.setattr(pipeline, "run_experiment", lambda *a, **k: pytest.fail("an invalid config was run"))
    with pytest.raises(ConfigError) as err:
        resolve_and_validate(compose_cfg(overrides))
    lines = [str(i) for i in err.value.issues]
    assert any(line.startswith(path) and hint in line for line in lines), lines


def test_all_problems_are_reported_together():
    with pytest.raises(ConfigError) as err:
        resolve_and_validate(
            compose_cfg(["expert.goal.type=rfb", "+tree.nodes.goal.rmp.gian=2", "tree.nodes.goal.map.origin=gaol"])
        )
    paths = {i.path for i in err.value.issues}
    assert {"expert.goal.type", "tree.nodes.goal.rmp.gian", "tree.nodes.goal.map.origin"} <= paths


def _cli(*args, timeout=300, cwd="/"):
    env = {**os.environ, "WANDB_MODE": "disabled", "HYDRA_FULL_ERROR": "0"}
    return subprocess.run(
        [sys.executable, "-m", *args], capture_output=True, text=True, timeout=timeout, cwd=cwd, env=env
    )


def test_cli_bad_config_exits_nonzero_without_traceback(tmp_path):
    r = _cli("rmpfusion.cli.run", "expert.goal.type=rfb", "+tree.nodes.goal.rmp.gian=2", f"hydra.run.dir={tmp_path}")
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr and "expert.goal.type" in r.stderr and "did you mean 'gain'" in r.stderr
    assert not (tmp_path / "data").exists() and not (tmp_path / "metrics.json").exists()


def test_validate_cli_from_any_cwd_prints_tree(tmp_path):
    r = _cli("rmpfusion.cli.validate", "experiment=2d2level", f"hydra.run.dir={tmp_path}", cwd=str(tmp_path))
    assert r.returncode == 0, r.stderr
    assert "└── obstacles (dim 2)" in r.stdout and "OK:" in r.stdout


# --------------------------------------------------------------------------- sweeps
@pytest.mark.slow
def test_sweep_all_experiments_tiny(tmp_path):
    """-m experiment=glob(*) on tiny sizes runs the whole pipeline once per experiment."""
    r = _cli("rmpfusion.cli.run", "-m", "experiment=glob(*)", *TINY, f"hydra.sweep.dir={tmp_path}", timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    metrics = sorted(tmp_path.glob("*/metrics.json"))
    assert len(metrics) == len(EXPERIMENTS), (metrics, r.stderr[-2000:])


@pytest.mark.slow
def test_submitit_local_two_jobs(tmp_path):
    r = _cli(
        "rmpfusion.cli.validate",
        "-m",
        "hydra/launcher=submitit_local",
        "seed=1,2",
        f"hydra.sweep.dir={tmp_path}",
        "hydra.launcher.timeout_min=5",
        timeout=600,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    assert len(sorted(tmp_path.glob(".submitit/*/*_result.pkl"))) == 2
    # Each job ran in its own submitit process and validated its own override; rmpfusion-validate keeps no run
    # directory, so the jobs' logs say which directory a run with those overrides would write.
    said = sorted(
        line.split()[2].rsplit("/", 1)[-1]
        for log in tmp_path.glob(".submitit/*/*_log.out")
        for line in log.read_text().splitlines()
        if line.startswith("run directory: ")
    )
    assert said == ["0_default_seed=1", "1_default_seed=2"]  # no experiment=: the default config, each job's override
    assert not list(tmp_path.glob("*/.hydra")), "rmpfusion-validate left a run directory behind"


@pytest.mark.slow
def test_optuna_sweep_searches_and_reports_the_best_learning_rate(tmp_path):
    """conf/sweep/optuna_lr.yaml: two tiny trials, each a full run whose returned loss Optuna minimises."""
    r = _cli(
        "rmpfusion.cli.run",
        "-m",
        "experiment=2d1level",
        "sweep=optuna_lr",
        "data=tiny",
        "train=tiny",
        "eval=fast",
        "logger=disabled",
        "hydra.sweeper.n_trials=2",
        f"hydra.sweep.dir={tmp_path}",
        timeout=600,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    best = (tmp_path / "optimization_results.yaml").read_text()
    assert "train.lr" in best and "best_value" in best
    assert len(list(tmp_path.glob("*_2d1level_*train.lr=*/metrics.json"))) == 2  # each trial's values in its name


@pytest.mark.parametrize("preset", sorted(p.stem for p in (CONF / "eval").glob("*.yaml")))
def test_every_eval_preset_lists_every_evaluation_setting(preset):
    """A setting missing from a preset cannot be overridden without Hydra's ``+`` (``eval.unit_weights=true`` on
    experiment=franka was refused): every conf/eval preset lists every key of EvalConfig."""
    import yaml

    from rmpfusion.pipeline.config import EvalConfig

    listed = set(yaml.safe_load((CONF / "eval" / f"{preset}.yaml").read_text()) or {})
    assert set(EvalConfig.model_fields) <= listed, (
        f"conf/eval/{preset}.yaml lacks {set(EvalConfig.model_fields) - listed}"
    )


@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_no_experiment_overrides_the_evaluation_preset_a_command_chooses(experiment):
    """An experiment's own keys are merged after the config groups, so an ``eval:`` block in it would silently undo
    ``eval=fast`` on the command line (experiment=lasa eval=fast drew every figure): experiments choose an eval
    preset in their defaults instead, which the command line's choice replaces."""
    import yaml

    own = yaml.safe_load((CONF / "experiment" / f"{experiment}.yaml").read_text()) or {}
    assert "eval" not in own, f"conf/experiment/{experiment}.yaml sets eval keys; choose a conf/eval preset instead"


def test_eval_fast_turns_the_figures_off_on_recorded_demonstrations():
    """The preset a command chooses wins over the one the experiment chose (Hydra's command-line overrides are
    applied after the experiment's defaults list)."""
    chosen = compose_cfg(["experiment=lasa", "eval=fast"])
    default = compose_cfg(["experiment=lasa"])
    assert chosen.eval.figures is False and default.eval.figures is True
    assert default.eval.unit_weights is False and default.eval.compile == "auto"  # each tree where compiling pays
