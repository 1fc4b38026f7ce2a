"""The run configuration: what a composed Hydra config must be once resolved.

Hydra composes YAML; this model is the contract every entry point validates against (frozen,
unknown keys rejected). Registry-typed blocks (env, learners, weights) are checked again by their
entry's own model in ``validate_run_config``, so errors name paths like ``learners.rmp.weights.hidden``.
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import Annotated, Any, Literal, Mapping

from pydantic import (BaseModel, BeforeValidator, ConfigDict, Field, ValidationError, create_model,
                      field_validator, model_validator)
from pydantic_core import InitErrorDetails, PydanticCustomError

from ..assembly.spec import TreeSpec, TypedBlock, tree_spec_model, typed_union, weight_field
from ..envs.common import time_grid
from ..learn import methods  # noqa: F401  (the built-in training methods register themselves)
from ..learn.config import DEFAULT_METHOD, RENAMED_KEYS, TrainConfig, TrainParams, _renamed, upgrade_train_config  # noqa: F401
from ..registry import ENVS, LEAF_RMPS, LEARNERS, TASK_MAPS, TRAIN_METHODS, WEIGHTS


class _Frozen(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class DataConfig(_Frozen):
    """Demonstrations (paper §4.1 "Data"): environments × trajectories × equidistant points."""

    train_envs: int = Field(20, gt=0)
    train_trajectories: int = Field(50, gt=0, description="per environment, from unique initial states")
    test_envs: int = Field(5, gt=0)
    test_trajectories: int = Field(10, gt=0)
    val_envs: int = Field(0, ge=0, description="validation environments, drawn like the training ones (never "
                                               "trained on): settings are chosen on this split, never on the test set")
    val_trajectories: int = Field(10, gt=0)
    points: int = Field(60, gt=1, description="recorded points per trajectory")
    interval: float = Field(1.0, gt=0, description="seconds between recorded points")
    cache_dir: str | None = Field(None, description="shared, checksummed dataset cache; default: the run directory")

    @field_validator("cache_dir")
    @classmethod
    def _a_directory(cls, v: str | None) -> str | None:
        """A cache that exists as something else than a directory could never hold a dataset: said now, not when
        the first dataset is written."""
        if v is not None:
            blocking = next((p for p in (Path(v), *Path(v).parents) if p.exists()), None)
            if blocking is not None and not blocking.is_dir():
                raise ValueError(f"{blocking} is a file, not a directory, so no dataset can be cached "
                                 f"{'in' if blocking == Path(v) else 'below'} it; point data.cache_dir at a directory "
                                 "(it is created if missing), or leave it out to keep data in the run directory")
        return v


def upgrade_run_config(run: Mapping[str, Any]) -> dict[str, Any]:
    """A stored run config (a checkpoint's ``config``, a run directory's config.resolved.yaml) with renamed keys
    under their current names (``RENAMED_KEYS``) and training keys added since at the values it was made with
    (``upgrade_train_config``); anything else is returned unchanged."""
    out = dict(run)
    for block, names in RENAMED_KEYS.items():
        if isinstance(out.get(block), Mapping):
            out[block] = _renamed(out[block], names)
    if isinstance(out.get("train"), Mapping):
        out["train"] = upgrade_train_config(out["train"])
    return out


def train_union() -> Any:
    """The training block: ``{method: name, ...}`` validated by the named entry of ``TRAIN_METHODS``; a block
    without ``method`` is behavior cloning (``DEFAULT_METHOD``), as every block was before methods existed."""
    return typed_union(TRAIN_METHODS, key="method", default=DEFAULT_METHOD)


def _typed_train(value: Any) -> Any:
    """The static ``RunConfig``'s training block, typed by its method's entry at validation time (so a plugin's
    method is known once its plugin loads); ``run_config_model`` types it the same way with error locations."""
    if isinstance(value, TrainParams):
        return value
    block = create_model("TrainBlock", train=(train_union(), ...))
    return block.model_validate({"train": value if value is not None else {}}).train


class EvalConfig(_Frozen):
    horizon: float | None = Field(None, gt=0, description="rollout length in seconds; default points × interval")
    lyapunov_rtol: float = Field(1e-6, ge=0)
    lyapunov_atol: float = Field(1e-9, ge=0)
    figures: bool = True
    compile: bool = Field(False, description="roll out through torch.compile'd trees (same numbers, faster "
                                             "after a one-off compile per tree)")
    unit_weights: bool = Field(False, description="also roll out the expert's tree with every weight 1 (RMPflow) "
                                                  "from the test starts: what the expert's weights add")


class LoggerConfig(_Frozen):
    mode: Literal["offline", "online", "disabled"] = "offline"
    project: str = "rmpfusion"
    entity: str | None = None
    tags: list[str] = Field(default_factory=list)
    group: str | None = None


class RunConfig(_Frozen):
    """A whole experiment: environment, tree, expert weights, learners, data, training, evaluation.

    This is the static form (registry-typed blocks as ``{type: name, ...}``); ``run_config_model`` is the same
    schema with every such block a discriminated union over its registry, and validated configs are
    instances of it."""

    name: str = "experiment"
    seed: int = 0
    device: str = Field("cpu", description="where trees, learners, training and the 2D environment compute: cpu, "
                                           "cuda or cuda:<index> (pybullet stays on the CPU; a policy's tensors cross "
                                           "once a step)")
    env: TypedBlock
    tree: TreeSpec = Field(description="the tree spec (docs/architecture.md §2) without learned weights")
    expert: dict[str, Any] = Field(default_factory=dict, description="node or shared-weight name -> weight spec")
    learners: dict[str, TypedBlock] = Field(default_factory=dict, description="learner name -> {type: rmp|unstructured, ...}")
    data: DataConfig = DataConfig()
    train: Annotated[Any, BeforeValidator(_typed_train)] = Field(
        default_factory=dict, validate_default=True,
        description="the training method (method: bc | dagger | apg | pg | a plugin's) and its settings")
    eval: EvalConfig = EvalConfig()
    logger: LoggerConfig = LoggerConfig()

    @field_validator("device")
    @classmethod
    def _device_form(cls, v: str) -> str:
        """cpu, cuda or cuda:<index>; torch's other names for a GPU are answered with torch's (gpu -> cuda)."""
        if re.fullmatch(r"cpu|cuda(:\d+)?", v):
            return v
        guess = re.sub(r"^(gpu|nvidia|cuda)\s*:?\s*(\d*)$", lambda m: "cuda" + (f":{m[2]}" if m[2] else ""), v.lower())
        hint = f"; did you mean {guess!r}?" if re.fullmatch(r"cpu|cuda(:\d+)?", guess) else ""
        raise ValueError(f"{v!r} is not a device torch knows{hint} (devices: cpu, cuda, cuda:<index>)")

    @model_validator(mode="after")
    def _across_blocks(self):
        """Checks that need two blocks at once, each reported at the key to change (all of them together)."""
        found: list[InitErrorDetails] = []

        def refuse(loc: tuple[str, ...], given: Any, message: str) -> None:
            found.append(InitErrorDetails(type=PydanticCustomError("run_config", "{message}", {"message": message}),
                                          loc=loc, input=given))

        bad = [s for s in self.train.snapshots if s < 0 or s > self.train.iterations] \
            if isinstance(self.train, TrainParams) else []
        if bad:
            refuse(("train", "snapshots"), bad,
                   f"snapshots {bad} lie outside 0..train.iterations={self.train.iterations} (a snapshot is the "
                   f"learner after that many iterations); given {self.train.snapshots}")
        step = getattr(self.env, "integration_step", None) if not isinstance(self.env, TypedBlock) else None
        if callable(step):  # environments that name their fixed step; others are checked when they roll out
            dt, key = step()
            if (too_many := self._too_many_steps(dt, key)) is not None:
                refuse(("env", key.split("env.", 1)[1]), dt, too_many)
            for loc, t, what in ((("data", "interval"), self.data.interval, "a positive multiple"),
                                 (("eval", "horizon"), self.eval.horizon, "a multiple")):
                if t is not None and not _on_grid(t, dt):
                    refuse(loc, t, f"must be {what} of the environment's step {key} = {dt:.6g} s (rollouts "
                                   f"integrate and record on that step's grid only); given {t}")
        shown = getattr(self.env, "render_trajectory", None) if not isinstance(self.env, TypedBlock) else None
        n_test = self.data.test_envs * self.data.test_trajectories
        if isinstance(shown, int) and shown >= n_test:
            refuse(("env", "render_trajectory"), shown,
                   f"must be < {n_test}, the number of test trajectories (data.test_envs × data.test_trajectories, "
                   f"numbered from 0); given {shown}")
        if found:
            raise ValidationError.from_exception_data(type(self).__name__, found)
        return self


    def _too_many_steps(self, dt: float, key: str) -> str | None:
        """Why a rollout on the step ``dt`` (set by ``key``) would never end, or None: its longest rollout (the
        demonstrations', the evaluation's, a training method's) must take at most ``MAX_ROLLOUT_STEPS`` steps."""
        horizons = [(self.data.points * self.data.interval, "data.points × data.interval"),
                    (self.eval.horizon, "eval.horizon"), (getattr(self.train, "horizon", None), "train.horizon")]
        horizon, what = max(((h, w) for h, w in horizons if h is not None), key=lambda hw: hw[0])
        steps = horizon / dt
        if steps <= MAX_ROLLOUT_STEPS:
            return None
        rate = f"{1 / dt:.3g} Hz" if 1 / dt < float("inf") else "an infinite rate"
        return (f"a step of {dt:.3g} s ({key}, a control rate of {rate}) makes a rollout of {horizon:g} s ({what}) "
                f"take {steps:.3g} integration steps, more than the {MAX_ROLLOUT_STEPS:.0e} a run allows (it would "
                f"never finish); use a step of at least {horizon / MAX_ROLLOUT_STEPS:.3g} s")


#: The most integration steps one rollout may take: a million steps of a 2-D particle take minutes, of an arm in
#: pybullet an hour; beyond it a step is a typo (``env.dt=1e-300``), not a setting.
MAX_ROLLOUT_STEPS = 1_000_000


def _on_grid(t: float, dt: float) -> bool:
    """Whether a rollout can record every ``t`` seconds on the step ``dt``: the rollout's own check, ``time_grid``."""
    try:
        time_grid(t, t, dt)
    except ValueError:
        return False
    return True


_RUN_MODELS: dict[tuple, type[RunConfig]] = {}


def run_config_model() -> type[RunConfig]:
    """``RunConfig`` typed by the registries as they are now: env, tree blocks, expert weights, learners and the
    training method are validated by their entries' own models (regenerated when an entry is registered, plugins included)."""
    registries = (ENVS, LEARNERS, TASK_MAPS, WEIGHTS, LEAF_RMPS, TRAIN_METHODS)
    for r in registries:
        r.load_plugins()  # first: a plugin's entries belong to the schema and to its cache key
    key = tuple((id(r), r.version) for r in registries)
    if key not in _RUN_MODELS:
        _RUN_MODELS[key] = create_model(
            "TypedRunConfig", __base__=RunConfig,
            env=(typed_union(ENVS), ...),
            tree=(tree_spec_model(), Field(description="the tree spec without learned weights")),
            expert=(dict[str, weight_field()], Field(default_factory=dict)),
            learners=(dict[str, typed_union(LEARNERS)], Field(default_factory=dict)),
            train=(train_union(), Field(default_factory=dict, validate_default=True)))
    return _RUN_MODELS[key]
