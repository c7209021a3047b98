"""rl-zoo-style YAML hyperparameters: load, validate, and reject anything unknown or out of range."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import yaml
from stable_baselines3.common.utils import LinearSchedule

from sb3_memret.memory.retention import RETENTION_RULES
from sb3_memret.memory.schema import AGE_UNITS
from sb3_memret.memory.stores import TIMESCALES, age_units, check_stores
from sb3_memret.tasks import check_task_name, make_task, task_in

ZOO_CONFIGS = Path(__file__).resolve().parents[2] / "zoo_configs"  # the shipped hyperparameters, one file per family

Check = tuple[type | tuple[type, ...], Callable[[Any], bool], str]


def _are_stores(value: list) -> bool:
    """Whether ``value`` lists a multi-timescale memory's stores (``check_stores`` says why not)."""
    check_stores(value)
    return True


def _is_task(value: str) -> bool:
    """Whether ``value`` names a task (``check_task_name``: a registered name, or a ``module:Class`` that imports);
    a ValueError says why not, and ``_validate`` passes it on."""
    check_task_name(value)
    return True


def _are_tasks(value: list | dict) -> bool:
    """Whether ``value`` lists tasks for one learner (``tasks:``): two or more task names, each as ``task`` takes
    it; as a mapping, each name's env settings of its own (``{InterceptSlow-VLA-v0: {success_bonus: 1.0}}``)."""
    names = list(value)
    if len(names) < 2 or len(set(names)) != len(names):
        raise ValueError("a learner across tasks needs two or more distinct tasks (one task: env_kwargs.task)")
    for name in names:
        if not isinstance(name, str):
            raise ValueError(f"a task name must be a string, got {name!r}")
        check_task_name(name)
    if isinstance(value, dict):
        for name, own in value.items():
            keys = {k: v for k, v in ENV_KEYS.items() if k not in MULTI_TASK_SHARED + ("task", "tasks")}
            _validate(own or {}, {**keys, **make_task(name).option_checks()}, f"tasks.{name}")
    return True


def learning_rate_schedule(value: float | str) -> float | LinearSchedule | None:
    """A config's ``learning_rate`` as PPO takes it: a number > 0 as it is; rl-zoo's ``lin_X`` (X > 0) as SB3's
    ``LinearSchedule`` from X at the run's start to 0 at its end; None for anything else."""
    if isinstance(value, str):
        number = value.removeprefix("lin_")
        try:
            start = float(number) if number != value else None
        except ValueError:
            return None
        return LinearSchedule(start, 0.0, 1.0) if start is not None and 0 < start < math.inf else None
    return value if 0 < value < math.inf else None


def _positive_int() -> Check:
    return (int, lambda v: v >= 1, "an integer >= 1")


def _unit() -> Check:
    return ((int, float), lambda v: 0 < v <= 1, "a number in (0, 1]")


PPO_KEYS: dict[str, Check] = {
    "n_timesteps": _positive_int(),
    "n_envs": _positive_int(),
    "eval_episodes": _positive_int(),  # held-out episodes per evaluation (train's --eval-episodes overrides)
    "eval_every": _positive_int(),  # rounds between evaluations, round 0 and the last always evaluated
    # held-out episodes of round 0's evaluation (the untrained learner's, whose episodes tend to run to the time
    # limit); default eval_episodes
    "initial_eval_episodes": _positive_int(),
    # held-out episodes of the evaluation at training's end, the final figure (the report's baselines play the same
    # episodes); default eval_episodes
    "final_eval_episodes": _positive_int(),
    "n_steps": _positive_int(),
    "batch_size": _positive_int(),
    "n_epochs": _positive_int(),
    "gamma": _unit(),
    "gae_lambda": _unit(),
    "learning_rate": ((int, float, str), lambda v: learning_rate_schedule(v) is not None,
                      "a number > 0, or 'lin_<number>' (rl-zoo's: falls linearly from that number to 0 at the run's end)"),
    "clip_range": ((int, float), lambda v: 0 < v < 1, "a number in (0, 1)"),
    "ent_coef": ((int, float), lambda v: v >= 0, "a number >= 0"),
    "vf_coef": ((int, float), lambda v: v >= 0, "a number >= 0"),
    "calibration_coef": ((int, float), lambda v: v >= 0, "a number >= 0 (0: keep-scores learn from the value loss only)"),
    "advantage_std_floor": ((int, float), lambda v: 0 <= v <= 1, "a number in [0, 1] (the least spread a round's "
                            "advantages are divided by, as a fraction of the widest so far; 0: always unit spread)"),
}
RUN_KEYS = ("n_timesteps", "n_envs", "eval_episodes", "eval_every", "initial_eval_episodes", "final_eval_episodes")  # how a run goes, not PPO's arguments
DEFAULT_EVAL_EPISODES, DEFAULT_EVAL_EVERY = 50, 5
POLICY_KEYS: dict[str, Check] = {
    "temperature": ((int, float), lambda v: v > 0, "a number > 0"),
    "hidden": _positive_int(),
    "retriever": (str, lambda v: v in ("mlp", "set"), "one of 'mlp' (per memory), 'set' (attention over the bank)"),
    "retriever_lr_scale": ((int, float), lambda v: v >= 0, "a number >= 0 (the retriever's learning rate over the "
                           "critic's; 0 freezes it)"),
    "context_lr_scale": ((int, float), lambda v: v >= 0, "a number >= 0 (the set retriever's attention rate over "
                         "its per-memory path's; 0 freezes it)"),
    "exploration": (str, lambda v: v in ("decision", "episode"), "one of 'decision' (fresh Plackett-Luce noise at "
                    "every decision), 'episode' (one draw per episode)"),
}
ENV_KEYS: dict[str, Check] = {
    "task": (str, _is_task, "a registered task or package.module:Class naming a Task of your own"),
    "tasks": ((list, dict), _are_tasks, "a list of tasks for one learner across them, or a mapping from each to "
              "its own env settings"),
    "mode": (str, lambda v: v in ("recall", "oracle", "none"), "one of 'recall', 'oracle', 'none'"),
    "capacity": _positive_int(),
    "k": _positive_int(),
    "replan_every": _positive_int(),
    "replans_per_decision": _positive_int(),
    "retrieve_on_write": (bool, lambda v: True, "true or false (a decision ends when its writer adds a fact)"),
    "max_control_steps": _positive_int(),
    "success_bonus": ((int, float), lambda v: v >= 0, "a number >= 0"),
    "location_decoys": (int, lambda v: v >= 0, "an integer >= 0"),
    "holding_decoys": (int, lambda v: v >= 0, "an integer >= 0"),
    "event_every": (int, lambda v: v >= 0, "an integer >= 0 (control steps between event decoys; 0: none)"),
    "long_term_capacity": (int, lambda v: v >= 0, "an integer >= 0 (0: no long-term store)"),
    "retention": (str, lambda v: v in RETENTION_RULES, f"one of {list(RETENTION_RULES)}"),
    "tasks_per_episode": _positive_int(),
    "age_unit": (str, lambda v: v in AGE_UNITS, f"one of {list(AGE_UNITS)} (what a memory's age counts)"),
    "stores": (list, _are_stores, f"a list of stores, each a mapping with timescale (one of {list(TIMESCALES)}), "
               "capacity and optionally age_unit and retention"),
    "observe_potential": (bool, lambda v: True, "true or false (the critic subtracts the shaping potential)"),
    "memory_source": (str, lambda v: v in ("seeded", "observed"), "one of 'seeded' (from the placement), "
                      "'observed' (from what the robot saw)"),
}


# what every task of a learner across tasks shares: one observation and action space, one critic's age unit
MULTI_TASK_SHARED = ("capacity", "long_term_capacity", "k", "observe_potential", "age_unit", "stores")


class MissingSectionError(ValueError):
    """A config file without a section for the env id (task) asked for."""


@dataclass
class TrainConfig:
    """Validated hyperparameters for one env id."""

    env_id: str
    ppo: dict[str, Any]
    policy_kwargs: dict[str, Any] = field(default_factory=dict)
    env_kwargs: dict[str, Any] = field(default_factory=dict)

    @property
    def n_timesteps(self) -> int:
        return self.ppo["n_timesteps"]

    @property
    def n_envs(self) -> int:
        """Parallel envs (a learner across tasks: per task)."""
        return self.ppo.get("n_envs", 1)

    @property
    def task_names(self) -> list[str]:
        """The tasks this config trains on: its ``tasks``, else its one ``task``."""
        return list(self.env_kwargs["tasks"]) if "tasks" in self.env_kwargs else [task_in(self.env_kwargs)]

    @property
    def eval_episodes(self) -> int:
        """Held-out episodes per evaluation."""
        return self.ppo.get("eval_episodes", DEFAULT_EVAL_EPISODES)

    @property
    def initial_eval_episodes(self) -> int | None:
        """Held-out episodes of round 0's evaluation; None: as many as every other's."""
        return self.ppo.get("initial_eval_episodes")

    @property
    def final_eval_episodes(self) -> int | None:
        """Held-out episodes of the evaluation at training's end; None: as many as every other's."""
        return self.ppo.get("final_eval_episodes")

    @property
    def eval_every(self) -> int:
        """Rounds between held-out evaluations."""
        return self.ppo.get("eval_every", DEFAULT_EVAL_EVERY)

    def algo_kwargs(self) -> dict[str, Any]:
        """Keyword arguments for MemRetPPO (everything but the run's length, env count and evaluations)."""
        kwargs = {k: v for k, v in self.ppo.items() if k not in RUN_KEYS}
        if "learning_rate" in kwargs:
            kwargs["learning_rate"] = learning_rate_schedule(kwargs["learning_rate"])
        policy_kwargs = dict(self.policy_kwargs)
        if self.env_kwargs.get("stores"):  # the critic reads ages in the units the env's stores count them in
            policy_kwargs["age_unit"] = age_units(check_stores(self.env_kwargs["stores"]))
        elif "age_unit" in self.env_kwargs:
            policy_kwargs["age_unit"] = self.env_kwargs["age_unit"]
        return {**kwargs, "policy_kwargs": policy_kwargs}


def read_yaml(path: str | Path, what: str = "config file") -> Any:
    """The YAML document in ``path``; a FileNotFoundError naming the ``what`` that is missing, or a ValueError giving
    the line and column where the YAML goes wrong."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no {what} at {str(path)!r}")
    try:
        return yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(err, "problem", None) or str(err).splitlines()[0]
        raise ValueError(f"{path} is not valid YAML{where}: {problem}") from None


def load_config(path: str | Path, env_id: str) -> TrainConfig:
    """Read ``path`` and return the validated section for ``env_id``."""
    data = read_yaml(path)
    if not isinstance(data, dict) or env_id not in data:
        known = list(data) if isinstance(data, dict) else []
        raise MissingSectionError(f"{path}: no section for env id {env_id!r}; the file has {known}")
    return parse_section(data[env_id], env_id, where=str(path))


def load_task_config(task: str, path: Path | None = None) -> TrainConfig:
    """The hyperparameters of ``task``: its section (``Task.config_key``) of ``path``, by default of the task's own
    zoo config (``Task.zoo_config``). Without ``path``, a task that has no section there (a task of your own) is
    told where they were looked for and how to pass them: no other task's section stands in for its own."""
    the_task = make_task(task)
    default = ZOO_CONFIGS / the_task.zoo_config
    try:
        return load_config(path or default, the_task.config_key)
    except (FileNotFoundError, MissingSectionError) as err:
        if path is not None:
            raise
        raise MissingSectionError(f"no hyperparameters for task {task!r}: its zoo config ({err}); pass --config "
                                  f"FILE, a YAML with a section {the_task.config_key!r} (the task's config_key), e.g. "
                                  "a section of zoo_configs/ copied and renamed") from None


def resolve_task_settings(config: TrainConfig) -> TrainConfig:
    """``config`` with a ``tasks`` list made a mapping: each task's env settings of its own, taken from the task's
    own zoo section (its keys that the shared section leaves unset, ``MULTI_TASK_SHARED`` excepted), so a run folder
    records what each task played with. A mapping, or a single task, comes back as it is; a task with no section of
    its own plays with the shared settings alone."""
    tasks = config.env_kwargs.get("tasks")
    if not isinstance(tasks, list):
        return config
    settings = {}
    for name in tasks:
        try:
            own = load_task_config(name).env_kwargs
        except MissingSectionError:
            own = {}
        settings[name] = {key: value for key, value in own.items()
                          if key not in config.env_kwargs and key not in MULTI_TASK_SHARED + ("task",)}
    return TrainConfig(config.env_id, dict(config.ppo), dict(config.policy_kwargs),
                       {**config.env_kwargs, "tasks": settings})


def parse_section(section: Any, env_id: str, where: str = "config") -> TrainConfig:
    if not isinstance(section, dict):
        raise ValueError(f"{where}: section {env_id!r} must be a mapping, got {type(section).__name__}")
    section = dict(section)
    policy_kwargs = _validate(section.pop("policy_kwargs", {}) or {}, POLICY_KEYS, f"{where}: {env_id}.policy_kwargs")
    env_kwargs = section.pop("env_kwargs", {}) or {}
    env_kwargs = _validate(env_kwargs, env_keys(env_kwargs, f"{where}: {env_id}.env_kwargs"), f"{where}: {env_id}.env_kwargs")
    ppo = _validate(section, PPO_KEYS, f"{where}: {env_id}")
    if "n_timesteps" not in ppo:
        raise ValueError(f"{where}: {env_id} must set n_timesteps")
    if "task" in env_kwargs and "tasks" in env_kwargs:
        raise ValueError(f"{where}: {env_id}.env_kwargs sets both task and tasks; one task or a list of them")
    if env_kwargs.get("stores"):
        clash = sorted({"capacity", "long_term_capacity", "age_unit"} & set(env_kwargs))
        if clash:
            raise ValueError(f"{where}: {env_id}.env_kwargs sets stores and {clash}: each store gives its own "
                             "capacity and age unit")
        slots = sum(store.capacity for store in check_stores(env_kwargs["stores"]))
    else:
        slots = env_kwargs.get("capacity", 6) + env_kwargs.get("long_term_capacity", 0)
    if "k" in env_kwargs and env_kwargs["k"] > slots:
        raise ValueError(f"{where}: {env_id}.env_kwargs: k={env_kwargs['k']} exceeds capacity={slots}")
    initial, every = ppo.get("initial_eval_episodes"), ppo.get("eval_episodes", DEFAULT_EVAL_EPISODES)
    if initial is not None and initial > every:
        raise ValueError(f"{where}: {env_id}: initial_eval_episodes={initial} exceeds eval_episodes={every}; round 0's "
                         "evaluation plays at most as many episodes as the others")
    final = ppo.get("final_eval_episodes")
    if final is not None and final < every:
        raise ValueError(f"{where}: {env_id}: final_eval_episodes={final} is below eval_episodes={every}; the final "
                         "evaluation plays at least as many episodes as the others")
    return TrainConfig(env_id, ppo, policy_kwargs, env_kwargs)


def env_keys(env_kwargs: Any, where: str) -> dict[str, Check]:
    """The keys ``env_kwargs`` may set: the decision env's (``ENV_KEYS``) and the options of the task(s) they name
    (``Task.option_checks``: the drawer's objects and households)."""
    named = _validate({k: v for k, v in env_kwargs.items() if k in ("task", "tasks")} if isinstance(env_kwargs, dict)
                      else env_kwargs, ENV_KEYS, where)
    keys = dict(ENV_KEYS)
    for name in list(named["tasks"]) if "tasks" in named else [task_in(named)]:
        keys.update(make_task(name).option_checks())
    return keys


def _validate(values: Any, spec: dict[str, Check], where: str) -> dict[str, Any]:
    if not isinstance(values, dict):
        raise ValueError(f"{where} must be a mapping, got {type(values).__name__}")
    for key, value in values.items():
        if key not in spec:
            raise ValueError(f"{where}: unknown key {key!r}; accepted keys are {sorted(spec)}")
        types, ok, expected = spec[key]
        if isinstance(value, bool) != (types is bool) or not isinstance(value, types):
            raise ValueError(f"{where}: {key}={value!r} is invalid; expected {expected}")
        try:
            valid = ok(value)
        except ValueError as err:  # a check that can say why (the task's)
            raise ValueError(f"{where}: {key}={value!r} is invalid: {err}") from None
        if not valid:
            raise ValueError(f"{where}: {key}={value!r} is invalid; expected {expected}")
    return dict(values)
