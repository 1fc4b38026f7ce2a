"""What a study file says, validated: its runs, the jobs they expand to, its tables and their pages.

A run is an experiment (``rmpfusion-run`` over conf/, with overrides) or a developer tool's command; ``seeds`` and
``sweep`` multiply it into jobs, each stored under ``results/<study>/<job>/``. A job's name is the run's name, then
each sweep value, then ``seed<k>`` when the run lists more than one seed: ``reach/iiwa``, ``franka/seed1``.
"""

from __future__ import annotations

import itertools
import re
from dataclasses import dataclass
from pathlib import Path

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from .tables import TABLE_KINDS

#: where a study file lives below the configuration directory
STUDY_GROUP = "study"
#: what a run's command may name besides its own job directory ({out}): the study's declared inputs
PLACEHOLDER = re.compile(r"\{(\w+)\}")


class StudyError(ValueError):
    """A study file, a study's name or its stored results are not what the command needs: the message says which
    file or key and what to do, in one line."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class StudyRun(_Strict):
    """One run of a study: an experiment over conf/ or a tool's command, multiplied by its seeds and sweep axes."""

    experiment: str | None = Field(None, description="conf/experiment/<name>: run with rmpfusion-run")
    command: str | None = Field(
        None,
        description="a developer tool's command line instead of an experiment; {out} is the job's directory, "
        "{<input>} one of the study's inputs",
    )
    overrides: list[str] = Field(default_factory=list, description="Hydra overrides (or the tool's arguments)")
    seeds: list[int] = Field(default_factory=lambda: [0], min_length=1, description="one job per seed")
    sweep: dict[str, list[str]] = Field(
        default_factory=dict, description="override key -> values: one job per combination, in the order given"
    )
    prepare: list[str] = Field(
        default_factory=list, description="commands run once before the run's jobs ({out}: the run's directory)"
    )

    @model_validator(mode="after")
    def _one_kind(self) -> StudyRun:
        if (self.experiment is None) == (self.command is None):
            raise ValueError("give either experiment (a conf/experiment/ name) or command (a tool's command line)")
        return self

    @field_validator("seeds")
    @classmethod
    def _distinct(cls, seeds: list[int]) -> list[int]:
        if len(set(seeds)) != len(seeds):
            raise ValueError(f"seeds {seeds} repeat a seed")
        return seeds

    def jobs(self, name: str) -> list[Job]:
        """Every job of this run, in the order the sweep lists them, seeds innermost."""
        axes = list(self.sweep.items())
        out = []
        for values in itertools.product(*(v for _, v in axes)):
            for seed in self.seeds:
                parts = [name, *values, *([f"seed{seed}"] if len(self.seeds) > 1 else [])]
                settings = tuple(f"{k}={v}" for (k, _), v in zip(axes, values, strict=True))
                out.append(Job("/".join(parts), name, seed, settings))
        return out


@dataclass(frozen=True)
class Job:
    """One run of one setting: where it is stored (``id``, below results/<study>/) and what makes it."""

    id: str
    run: str
    seed: int
    settings: tuple[str, ...]


class StudyTable(_Strict):
    """A table of a results page, regenerated from stored jobs by a table kind (rmpfusion/studies/tables/)."""

    kind: str = Field(description="how the rows are formatted: " + ", ".join(sorted(TABLE_KINDS)))
    page: str | None = Field(None, description="the page it is on (default: the study's page)")
    rows: dict[str, str] = Field(min_length=1, description="row label -> the stored job it is made from")

    @field_validator("kind")
    @classmethod
    def _known(cls, kind: str) -> str:
        if kind not in TABLE_KINDS:
            raise ValueError(f"unknown table kind '{kind}'; known: {', '.join(sorted(TABLE_KINDS))}")
        return kind


class Study(_Strict):
    """A study file: what it shows, the runs it is made of and the tables they make."""

    description: str = Field(min_length=1)
    page: str = Field(description="the results page its tables are on, from the repository root")
    inputs: dict[str, str] = Field(
        default_factory=dict, description="name -> what to pass (rmpfusion-study run NAME --input name=PATH)"
    )
    runs: dict[str, StudyRun] = Field(min_length=1)
    tables: dict[str, StudyTable] = Field(default_factory=dict)

    @model_validator(mode="after")
    def _rows_name_jobs(self) -> Study:
        jobs = {j.id for j in self.jobs()}
        for name, table in self.tables.items():
            unknown = [job for job in table.rows.values() if job not in jobs]
            if unknown:
                raise ValueError(
                    f"table {name}: rows name {unknown[:3]}, which no run of the study makes; "
                    f"its jobs are {sorted(jobs)[:6]}{' ...' if len(jobs) > 6 else ''}"
                )
        for name, run in self.runs.items():
            needed = set(PLACEHOLDER.findall(" ".join([run.command or "", *run.overrides, *run.prepare])))
            missing = needed - {"out"} - set(self.inputs)
            if missing:
                raise ValueError(f"run {name} names {sorted(missing)}, which the study's inputs do not declare")
        return self

    def jobs(self) -> list[Job]:
        return [job for name, run in self.runs.items() for job in run.jobs(name)]

    def page_of(self, table: str) -> str:
        return self.tables[table].page or self.page


def study_dir(config_dir: Path) -> Path:
    return config_dir / STUDY_GROUP


def study_names(config_dir: Path) -> list[str]:
    return sorted(p.stem for p in study_dir(config_dir).glob("*.yaml"))


def load_study(name: str, config_dir: Path) -> Study:
    """The study ``conf/study/<name>.yaml``, validated; a StudyError naming the file, the key and the fix."""
    path = study_dir(config_dir) / f"{name}.yaml"
    if not path.is_file():
        known = ", ".join(study_names(config_dir)) or "none"
        raise StudyError(f"no study '{name}': {path} does not exist (studies: {known})")
    try:
        raw = yaml.safe_load(path.read_text(encoding="utf-8"))
    except yaml.YAMLError as e:
        raise StudyError(f"{path}: not YAML ({' '.join(str(e).split())})") from None
    try:
        return Study.model_validate(raw)
    except ValidationError as e:
        said = [f"{'.'.join(str(p) for p in err['loc']) or '(top level)'}: {err['msg']}" for err in e.errors()]
        raise StudyError(f"{path}: " + "; ".join(said)) from None
