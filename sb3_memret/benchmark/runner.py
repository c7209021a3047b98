"""Run MIKASA-Robo-VLA's protocol: every task of a split, each condition, 50 seeded episodes, resumable.

One episode is one unit of work (task, condition, seed), played in MIKASA's harness by ``MemoryAgent``. Finished
episodes are appended to ``DIR/episodes.jsonl`` as they land, so an interrupted run resumes where it stopped;
``DIR/results.json`` and ``DIR/report.md`` are rewritten after every task. Episodes spread over worker processes,
each keeping one harness env per task (building one takes ~15 s). A task that cannot run here (no sb3-memret task,
a missing asset, no controller, no trained learner for ``recall``, an error in its episodes) is refused with its
reason, recorded in the results and the report; the run goes on with the others.
"""

from __future__ import annotations

import ast
import hashlib
import inspect
import json
import os
import sys
import time
import traceback
from collections import Counter, defaultdict
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator

from sb3_memret.benchmark.agent import CONDITIONS, check_conditions
from sb3_memret.benchmark.learners import find_learner, learner_path, learner_sources, learners_json, stored_learners
from sb3_memret.benchmark.manifest import episode_seeds, select_tasks
from sb3_memret.benchmark.mikasa_results import write_mikasa_results
from sb3_memret.controllers.pacing import replan_interval

EPISODES_FILE, RESULTS_FILE, PROTOCOL_FILE, ERRORS_FILE = "episodes.jsonl", "results.json", "protocol.json", "errors.log"
LOCK_FILE = ".lock"  # held by the benchmark playing the folder
WORKER_REPLACEMENTS = 3  # pools a table starts again after an episode worker died, before it stops with a resume hint


# what the episodes of a protocol.json written before a setting existed were played under
PREDATING: dict[str, Any] = {"fresh_scenes": False}


@dataclass(frozen=True)
class Protocol:
    """What every episode of a run shares; a run folder resumes only under the same protocol."""

    benchmark: str = "MIKASA-Robo-VLA"
    harness: str = "mikasa_robo_suite.vla.benchmarking (make_benchmark_env, run_episode)"
    wrapper_chain: str = "apply_mikasa_vla_wrappers(include_overlays=False)"
    control_mode: str = "pd_ee_delta_pose"
    obs_mode: str = "rgb"
    reward_mode: str = "normalized_dense"
    metric: str = "success_once"
    policy_inputs: tuple[str, ...] = ("rgb", "proprio", "instruction")
    seed_set: str = "dev"  # the test set ("protocol") only when asked for by name
    episodes: int = 50
    controller: str = "scripted"
    replan_every: int | None = None  # None: each task's own (Task.replan_every)
    sim_backend: str = "cpu"
    # every episode in a scene built anew (harness.make_env's fresh_scenes): none depends on a worker's earlier ones
    fresh_scenes: bool = True
    # tasks of one's own: (MIKASA env id, the ``package.module:Class`` that plays it) for each such task
    task_classes: tuple[tuple[str, str], ...] = ()

    def seeds(self) -> list[int]:
        return episode_seeds(self.seed_set, self.episodes)

    def task(self, env_id: str) -> str:
        """What ``make_task`` builds for ``env_id``: a task of one's own named for it, else the registered task."""
        return dict(self.task_classes).get(env_id, env_id)

    def to_json(self) -> dict[str, Any]:
        """The protocol as ``protocol.json`` holds it (lists for tuples)."""
        return json.loads(json.dumps(asdict(self)))

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> "Protocol":
        """The protocol ``to_json`` wrote; a key an older file lacks takes what its episodes were played under
        (``PREDATING``), else its default."""
        data = {**cls().to_json(), **PREDATING, **data}
        data["policy_inputs"] = tuple(data.get("policy_inputs", cls.policy_inputs))
        data["task_classes"] = tuple(tuple(pair) for pair in data.get("task_classes", ()))
        return cls(**data)

    def differing(self, other: "Protocol") -> list[str]:
        """The settings in which ``other`` differs from this protocol, sorted."""
        mine, theirs = self.to_json(), other.to_json()
        return sorted(k for k in set(mine) | set(theirs) if mine.get(k) != theirs.get(k))


def resolve_task_ids(ids: Iterable[str]) -> tuple[list[str], tuple[tuple[str, str], ...]]:
    """``--tasks``' entries as MIKASA env ids, and the tasks of one's own among them: a ``package.module:Class``
    entry is imported and plays the env its ``name`` gives, which must be one of the benchmark's."""
    from sb3_memret.benchmark.manifest import manifest_ids
    from sb3_memret.tasks import make_task

    env_ids, classes = [], []
    for entry in ids:
        if ":" not in entry:
            env_ids.append(entry)
            continue
        name = make_task(entry).name
        if name not in manifest_ids():
            raise ValueError(f"task {entry!r} plays {name!r} (its name), which is not a MIKASA-Robo-VLA benchmark "
                             f"task; a task of one's own runs in the benchmark under the env id of the MIKASA task it "
                             f"plays, e.g. {sorted(manifest_ids())[:3]}")
        env_ids.append(name)
        classes.append((name, entry))
    return env_ids, tuple(classes)


@dataclass(frozen=True)
class Unit:
    """One episode to play."""

    env_id: str
    condition: str
    seed: int


@dataclass
class Plan:
    """The tasks of a run and what becomes of each: the units to play, or the reason it is refused."""

    protocol: Protocol
    tasks: list[Any]  # MIKASA's BenchmarkTask rows, in order
    conditions: list[str]
    refused: dict[str, str] = field(default_factory=dict)  # env id -> why it cannot run here
    refused_conditions: dict[tuple[str, str], str] = field(default_factory=dict)  # (env id, condition) -> why
    controllers: dict[str, dict[str, str]] = field(default_factory=dict)  # env id -> {"name", "sha256", "reads"}
    task_digests: dict[str, str] = field(default_factory=dict)  # env id -> SHA-256 of its task's (writer's) code
    replan_every: dict[str, int] = field(default_factory=dict)  # env id -> control steps between controller calls
    learners: tuple[Path, ...] = ()  # the recall condition's learners (folders or model files), first serving first
    learner_digests: dict[str, str] = field(default_factory=dict)  # env id -> SHA-256 of its learner's model file

    def current(self, record: dict[str, Any]) -> bool:
        """Whether a logged episode was played by this plan's controller and task code (else it is played again)."""
        env_id = record["env_id"]
        return (env_id in self.controllers and record.get("controller_sha256") == self.controllers[env_id]["sha256"]
                and record.get("task_sha256") == self.task_digests[env_id]
                and (record["condition"] != "recall" or record.get("learner_sha256") == self.learner_digests.get(env_id)))

    def units(self, done: set[Unit]) -> list[Unit]:
        seeds = self.protocol.seeds()
        return [Unit(t.env_id, c, s) for t in self.tasks if t.env_id not in self.refused for c in self.conditions
                if (t.env_id, c) not in self.refused_conditions for s in seeds if Unit(t.env_id, c, s) not in done]


INTERFACE_MODULES = ("sb3_memret.tasks.base", "sb3_memret.controllers.base")  # interfaces and defaults, not digested


def code_digest(*classes: type) -> str:
    """SHA-256 of the code of ``classes`` and their sb3-memret base classes: each defining module's syntax tree
    without its docstrings, so an edited comment or docstring leaves it as it was and a changed line does not. A
    ``from X import name`` counts by the names it binds, not by ``X``: a helper moved to another module replays
    nothing. The two interface modules (``Task``, ``FrozenController``) are left out: they grow with every new task
    hook, and a long run's episodes should not be replayed for a hook its tasks do not use."""
    modules = sorted({k.__module__ for cls in classes for k in cls.__mro__
                      if k.__module__.startswith("sb3_memret") and k.__module__ not in INTERFACE_MODULES})
    digest = hashlib.sha256()
    for name in modules:
        tree = ast.parse(Path(inspect.getsourcefile(sys.modules[name])).read_text())
        for node in ast.walk(tree):
            body = getattr(node, "body", None)
            if isinstance(body, list) and body and isinstance(body[0], ast.Expr) \
                    and isinstance(body[0].value, ast.Constant) and isinstance(body[0].value.value, str):
                node.body = body[1:] or [ast.Pass()]
            if isinstance(node, ast.ImportFrom):
                node.module, node.level = None, 0
        digest.update(name.encode())
        digest.update(ast.dump(tree).encode())
    return digest.hexdigest()


def controller_digest(controller: Any) -> str:
    """SHA-256 of what makes the controller act as it does: a learned checkpoint's files, else its code."""
    checkpoint = getattr(controller, "checkpoint", None)
    if checkpoint is None or not Path(checkpoint).is_dir():
        return code_digest(type(controller))
    digest = hashlib.sha256()
    for path in sorted(p for p in Path(checkpoint).iterdir() if p.suffix in (".json", ".safetensors")):
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def task_digest(task: Any) -> str:
    """SHA-256 of the code of the task, its writer and its controller's view (``code_digest``)."""
    parts = [type(task), type(task.writer())]
    wrapper = getattr(task, "observation_wrapper", None)
    return code_digest(*parts, *([wrapper] if isinstance(wrapper, type) else []))


def _reason(err: BaseException, env_id: str) -> str:
    """An error's first clause: why, without the list of what would be accepted."""
    text = str(err).splitlines()[0]
    if text.startswith("unknown task"):
        return "no sb3-memret task implements it yet"
    for cut in ("; available tasks", "; expected one of"):
        text = text.split(cut)[0]
    return text.removeprefix("task ").split(" is not available: ")[-1]


def split_tasks(split: str) -> tuple[list[str], dict[str, str]]:
    """The tasks of MIKASA-Robo-VLA's ``split`` that run here, in the manifest's order, and why each of the others
    does not (a missing asset, no sb3-memret task)."""
    from sb3_memret.tasks import check_task_name

    runnable, refused = [], {}
    for row in select_tasks(split):
        try:
            runnable.append(check_task_name(row.env_id))
        except ValueError as err:
            refused[row.env_id] = _reason(err, row.env_id)
    return runnable, refused


def learners_landed(run: Plan) -> list[str]:
    """The tasks whose recall condition ``run`` refused for want of a learner that its learners folder now holds
    (``benchmark learners`` training beside the benchmark): a new plan plays their recall episodes."""
    return [env_id for (env_id, condition) in run.refused_conditions
            if condition == "recall" and learner_path(run.learners, env_id) is not None]


def learner_record(run: Plan, env_id: str) -> dict[str, Any]:
    """What a recall cell says of its learner: the model file, its SHA-256 (an episode counts only for the learner
    it was played with), and its training run's rounds and final held-out figures (development seeds)."""
    path = learner_path(run.learners, env_id)
    entry: dict[str, Any] = {"learner": None if path is None else str(path),
                             "learner_sha256": run.learner_digests.get(env_id)}
    summary = path.parent / "summary.json" if path is not None else None
    if summary is not None and summary.is_file():
        saved = json.loads(summary.read_text())
        final = saved.get("final_eval") or {}
        entry["learner_training"] = {"rounds": saved.get("rounds"), "seed": saved.get("seed"),
                                     "eval_episodes": final.get("episodes"),
                                     "eval_success": (final.get("success") or {}).get("overall"),
                                     "eval_greedy_accuracy": final.get("greedy_accuracy")}
    return entry


def plan(protocol: Protocol, conditions: Iterable[str], split: str | None = None,
         env_ids: Iterable[str] | None = None, learners: Path | Iterable[Path] | None = None) -> Plan:
    """Select the tasks (by split or ids) and decide, without simulating, which can run here and why not."""
    from sb3_memret.controller_specs import make_controller
    from sb3_memret.tasks import check_task_name, make_task

    tasks = select_tasks(split, list(env_ids) if env_ids is not None else None)
    result = Plan(protocol, tasks, check_conditions(list(conditions)), learners=learner_sources(learners))
    for row in tasks:
        try:
            check_task_name(protocol.task(row.env_id))
            task = make_task(protocol.task(row.env_id))
            controller = make_controller(protocol.controller, task)
        except (ValueError, FileNotFoundError, ImportError) as err:
            result.refused[row.env_id] = _reason(err, row.env_id)
            continue
        result.controllers[row.env_id] = controller_record(protocol.controller, controller)
        result.task_digests[row.env_id] = task_digest(task)
        result.replan_every[row.env_id] = replan_interval(task, protocol.replan_every, controller)
        if "recall" in result.conditions:
            path, why = find_learner(result.learners, row.env_id)
            if path is None:
                result.refused_conditions[row.env_id, "recall"] = why
            else:
                result.learner_digests[row.env_id] = hashlib.sha256(path.read_bytes()).hexdigest()
    return result


# ---------------------------------------------------------------- playing episodes (in workers)
class _Worker:
    """A worker's harness env and agents for the task it is playing (rebuilt when the task changes)."""

    def __init__(self, protocol: Protocol, learners: Path | Iterable[Path] | None):
        self.protocol, self.learners = protocol, learner_sources(learners)
        self.env_id: str | None = None
        self.env: Any = None
        self.agents: dict[str, Any] = {}
        self.encoder: Any = None
        self.failed: dict[tuple[str, str], str] = {}  # (env id, condition) -> the error its first episode met

    def agent(self, env_id: str, condition: str) -> Any:
        from sb3_memret.benchmark import harness
        from sb3_memret.benchmark.agent import MemoryAgent, MemoryLearner
        from sb3_memret.controller_specs import make_controller
        from sb3_memret.memory.encoder import MiniLMEncoder
        from sb3_memret.tasks import make_task

        if env_id != self.env_id:
            if self.env is not None:
                self.env.close()
            self.env_id, self.agents = None, {}
            self.env = harness.make_env(env_id, self.protocol.sim_backend, fresh_scenes=self.protocol.fresh_scenes)
            self.env_id = env_id
        if condition not in self.agents:
            task = make_task(self.protocol.task(env_id))
            self.encoder = self.encoder or MiniLMEncoder()
            learner = MemoryLearner(learner_path(self.learners, env_id), self.protocol.controller, env_id) \
                if condition == "recall" else None
            agent = MemoryAgent(task, make_controller(self.protocol.controller, task), condition,
                                self.protocol.replan_every, learner, self.encoder)
            agent.bind(self.env)
            self.agents[condition] = agent
        return self.agents[condition]

    def play(self, unit: Unit) -> dict[str, Any]:
        from sb3_memret.benchmark import harness

        if (unit.env_id, unit.condition) in self.failed:  # the same error again: not worth an episode
            return {**asdict(unit), "error": self.failed[unit.env_id, unit.condition]}
        try:
            agent = self.agent(unit.env_id, unit.condition)
            agent.begin(self.protocol.seeds().index(unit.seed))  # its place in the run, not the episode's seed
            start = time.perf_counter()
            result = harness.play_episode(self.env, agent, unit.seed)
            seconds = time.perf_counter() - start
        except Exception as err:  # recorded with the task, which the report then refuses
            error = f"{type(err).__name__}: {err}".splitlines()[0]
            self.failed[unit.env_id, unit.condition] = error
            return {**asdict(unit), "error": error, "traceback": traceback.format_exc()}
        return {**asdict(unit), "success": bool(result.success_once), "return": float(result.episode_return),
                "steps": int(result.n_steps), "seconds": round(seconds, 3),
                "prompt": agent.prompts[-1] if agent.prompts else None, "cue": cue_label(agent.episode)}


def cue_label(episode: Any) -> str | None:
    """What the episode's cue was, as its true facts' values (``blue``; a sequence's in order, ``red, lime, teal``):
    the key of the report's per-cue breakdown. Logged for the report only; no controller reads it."""
    if episode is None or not episode.true_facts:
        return None
    return ", ".join(str(value) for _, value in episode.true_facts)


_WORKER: _Worker | None = None


def _init_worker(protocol: Protocol, learners: tuple[Path, ...]) -> None:
    """A pool worker: Ctrl-C is the parent's (it stops the pool), SIGTERM ends it (the pool's terminate sends it)."""
    import signal

    from sb3_memret.common.workers import init_worker_process

    global _WORKER
    init_worker_process(ignored=(signal.SIGINT,))
    _WORKER = _Worker(protocol, learners)


def _play(unit: Unit) -> dict[str, Any]:
    return _WORKER.play(unit)


def play_units(units: list[Unit], protocol: Protocol, learners: Path | Iterable[Path] | None, workers: int,
               replacements: int = WORKER_REPLACEMENTS) -> Iterator[dict[str, Any]]:
    """Each unit's outcome as it lands: in this process for one worker (with one torch thread: beside other jobs,
    idle intra-op threads spin-wait after every op), else in ``workers`` spawned processes (each unit to the next
    free one; a task's units stay together in the queue, so envs are rebuilt rarely). A
    worker that dies is replaced and the units that had not landed are played again, up to ``replacements`` times
    (``common.workers.replaying_pool``); landed units are never replayed."""
    from sb3_memret.common.workers import replaying_pool, torch_threads

    if workers <= 1:
        worker = _Worker(protocol, learners)
        with torch_threads(1):  # as in every pool worker (scripts/bench_benchmark.py --threads)
            yield from (worker.play(unit) for unit in units)
        return

    for _, record in replaying_pool(_play, units, workers, _init_worker, (protocol, learner_sources(learners)), replacements,
                                    what="episodes"):
        yield record


# ---------------------------------------------------------------- the run folder
class RunFolder:
    """``DIR``: the protocol, the episode log, the results and the report."""

    def __init__(self, out: Path):
        self.out = Path(out)

    def protocol(self) -> Protocol | None:
        """The protocol the folder's episodes were played under (None for a folder without one yet)."""
        path = self.out / PROTOCOL_FILE
        return Protocol.from_json(json.loads(path.read_text())) if path.is_file() else None

    def check_protocol(self, protocol: Protocol) -> None:
        """Write the protocol of a new run; refuse to resume a run played under another one."""
        self.out.mkdir(parents=True, exist_ok=True)
        saved = self.protocol()
        if saved is None:
            (self.out / PROTOCOL_FILE).write_text(json.dumps(protocol.to_json(), indent=2) + "\n")
            return
        theirs = saved.to_json()
        diff = protocol.differing(saved)
        if diff:
            settings = ", ".join(f"{k}: {theirs[k]!r}" for k in diff)
            raise ValueError(f"{self.out} holds a run under another protocol ({settings}); resume it with the same "
                             "options, or choose another --out")

    @contextmanager
    def playing(self) -> Iterator[None]:
        """Hold the folder for one benchmark at a time (``DIR/.lock``, released when the process ends however it
        ends): a second one on the same folder would play every pending episode again beside it."""
        import fcntl

        self.out.mkdir(parents=True, exist_ok=True)
        with (self.out / LOCK_FILE).open("a+") as f:
            try:
                fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                f.seek(0)
                holder = f.read().strip() or "another process"
                raise ValueError(f"{self.out} is being played by another benchmark ({holder}); wait for it to end, "
                                 "or choose another --out") from None
            f.seek(0)
            f.truncate()
            f.write(f"process {os.getpid()}\n")
            f.flush()
            try:
                yield
            finally:
                fcntl.flock(f, fcntl.LOCK_UN)

    def episodes(self) -> list[dict[str, Any]]:
        """Every logged episode outcome (a line cut off by an interruption is skipped)."""
        path = self.out / EPISODES_FILE
        records = []
        for line in path.read_text().splitlines() if path.exists() else []:
            try:
                records.append(json.loads(line))
            except json.JSONDecodeError:
                continue
        return records

    def log(self, record: dict[str, Any]) -> None:
        trace = record.pop("traceback", None)
        with (self.out / EPISODES_FILE).open("a") as f:
            f.write(json.dumps(record) + "\n")
        if trace is not None:
            with (self.out / ERRORS_FILE).open("a") as f:
                f.write(f"{record['env_id']} {record['condition']} seed {record['seed']}\n{trace}\n")


def done_units(run: Plan, records: Iterable[dict[str, Any]]) -> set[Unit]:
    """The units that finished with the plan's controller and task code (an errored one is not done: a resumed run
    tries it again)."""
    return {Unit(r["env_id"], r["condition"], int(r["seed"])) for r in records if "error" not in r and run.current(r)}


def outdated(run: Plan, records: Iterable[dict[str, Any]]) -> dict[str, int]:
    """Per task of ``run`` that runs here, its episodes (task, condition, seed) logged only as played by other code
    (a changed controller or task digest): they no longer count in the table, and are played again only by a run
    that asks for the task."""
    records = [r for r in records if r["env_id"] in run.controllers and "error" not in r]
    current = {Unit(r["env_id"], r["condition"], int(r["seed"])) for r in records if run.current(r)}
    stale = {unit for r in records if (unit := Unit(r["env_id"], r["condition"], int(r["seed"]))) not in current}
    return dict(Counter(unit.env_id for unit in stale))


def results(run: Plan, records: Iterable[dict[str, Any]]) -> dict[str, Any]:
    """``results.json``'s content: the protocol, and per task its split, memory type, controller and each
    condition's success over the protocol's seeds (or why the task or condition was refused)."""
    seeds = run.protocol.seeds()
    latest: dict[Unit, dict[str, Any]] = {}
    errors: dict[tuple[str, str], str] = {}
    for r in records:
        if not run.current(r):
            continue
        unit = Unit(r["env_id"], r["condition"], int(r["seed"]))
        if "error" in r:
            errors[unit.env_id, unit.condition] = r["error"]
        else:
            latest[unit] = r
    tasks: dict[str, Any] = {}
    for row in run.tasks:
        entry: dict[str, Any] = {"split": row.split, "memory_type": row.memory_type,
                                 "max_episode_steps": row.max_episode_steps}
        if run.protocol.task(row.env_id) != row.env_id:  # a task of one's own plays it
            entry["task_class"] = run.protocol.task(row.env_id)
        if row.env_id in run.refused:
            tasks[row.env_id] = {**entry, "refused": run.refused[row.env_id]}
            continue
        entry["controller"] = run.controllers[row.env_id]
        entry["replan_every"] = run.replan_every[row.env_id]
        conditions: dict[str, Any] = {}
        for condition in run.conditions:
            if (row.env_id, condition) in run.refused_conditions:
                conditions[condition] = {"refused": run.refused_conditions[row.env_id, condition]}
                continue
            played = [latest[u] for s in seeds if (u := Unit(row.env_id, condition, s)) in latest]
            cell: dict[str, Any] = {"episodes": len(played), "seeds": [r["seed"] for r in played],
                                    "successes": [r["success"] for r in played],
                                    "returns": [r.get("return") for r in played],
                                    "episode_lengths": [r.get("steps") for r in played],
                                    "seconds": [r.get("seconds") for r in played],  # wall, in its worker
                                    "success": sum(r["success"] for r in played) / len(played) if played else None,
                                    "complete": len(played) == len(seeds)}
            cues = [r.get("cue") for r in played]
            if played and all(cues):  # episodes logged before cues were count in the table, not in the breakdown
                cell["by_cue"] = {cue: {"episodes": sum(c == cue for c in cues),
                                        "successes": sum(r["success"] for r in played if r["cue"] == cue)}
                                  for cue in sorted(set(cues))}
            if (row.env_id, condition) in errors and not cell["complete"]:
                cell["error"] = errors[row.env_id, condition]
            if condition == "recall":
                cell.update(learner_record(run, row.env_id))
            conditions[condition] = cell
        entry["conditions"] = conditions
        tasks[row.env_id] = entry
    protocol = {**run.protocol.to_json(), "conditions": run.conditions, "seeds": seeds}  # as results.json reads back
    protocol["learners"] = learners_json(run.learners)
    privileged = any(t.get("controller", {}).get("privileged") for t in tasks.values())
    return {"protocol": protocol, "privileged_upper_bound": privileged, "tasks": tasks}


def controller_record(name: str, controller: Any) -> dict[str, Any]:
    """What a table says of its frozen controller: its name, digest and what it reads; a controller that reads the
    simulator beyond the protocol's policy inputs (a scripted expert's simulated object detector, a camera policy's
    joint positions and velocities) is a privileged upper bound, and the record says so."""
    spec = controller.spec
    privileged = not spec.harness_inputs
    if spec.harness_inputs:
        reads = "the harness's inputs alone: both cameras and its 7-D proprioception (hand xyz, roll-pitch-yaw, gripper)"
    elif spec.needs_images:
        reads = ("cameras and robot state read from the simulator (joint positions and velocities, hand pose), "
                 "beyond the protocol's 7-D proprioception")
    else:
        reads = "proprioception and a simulated object detector (objects in sight), beyond the protocol's policy inputs"
    record = {"name": name, "sha256": controller_digest(controller), "reads": reads, "privileged": privileged}
    checkpoint = getattr(controller, "checkpoint", None)
    if checkpoint is not None and Path(checkpoint).is_dir():  # the weights it plays, each file's SHA-256 to check
        path = Path(checkpoint).resolve()
        from sb3_memret.controllers.shipped import CHECKPOINTS

        record["checkpoint"] = f"shipped: {path.name}" if path.parent == CHECKPOINTS else str(path)
        record["checkpoint_files_sha256"] = {p.name: hashlib.sha256(p.read_bytes()).hexdigest()
                                             for p in sorted(path.iterdir()) if p.is_file()}
    return record


def widened(run: Plan, out: Path) -> Plan:
    """``run`` widened to every task and condition that the run folder's ``results.json`` already reports, so that
    adding a condition (``recall`` once the learners exist) or a task to a run keeps its whole table; only ``run``'s
    own units are played."""
    saved = Path(out) / RESULTS_FILE
    if not saved.is_file():
        return run
    content = json.loads(saved.read_text())
    env_ids = [row.env_id for row in run.tasks]
    env_ids += [env_id for env_id in content["tasks"] if env_id not in env_ids]
    conditions = [c for c in CONDITIONS if c in run.conditions or c in content["protocol"]["conditions"]]
    if len(env_ids) == len(run.tasks) and conditions == run.conditions:
        return run
    return plan(run.protocol, conditions, env_ids=env_ids,
                learners=run.learners or stored_learners(content["protocol"].get("learners")))


def run_benchmark(run: Plan, out: Path, workers: int = 1,
                  on_progress: Callable[[int, int], None] | None = None,
                  on_task_done: Callable[[dict[str, Any]], None] | None = None,
                  on_outdated: Callable[[dict[str, int], set[str]], None] | None = None) -> dict[str, Any]:
    """Play every pending unit of ``run`` into ``out`` (resuming what is there), rewriting ``results.json`` (and
    calling ``on_task_done`` with it) whenever a task's condition has played its last pending unit; the final
    results. Before playing, ``on_outdated`` hears of the logged episodes that other code played (``outdated``, over
    the whole table the folder shows) and which of their tasks this run plays again."""
    folder = RunFolder(out)
    folder.check_protocol(run.protocol)
    with folder.playing():
        return _play_run(run, folder, workers, on_progress, on_task_done, on_outdated)


def _play_run(run: Plan, folder: RunFolder, workers: int,
              on_progress: Callable[[int, int], None] | None,
              on_task_done: Callable[[dict[str, Any]], None] | None,
              on_outdated: Callable[[dict[str, int], set[str]], None] | None = None) -> dict[str, Any]:
    records = folder.episodes()
    shown = widened(run, folder.out)
    stale = outdated(shown, records)
    if stale and on_outdated is not None:
        on_outdated(stale, {row.env_id for row in run.tasks if row.env_id in run.controllers})
    pending = run.units(done_units(run, records))
    left = defaultdict(int)
    for unit in pending:
        left[unit.env_id, unit.condition] += 1
    total, finished = len(pending), 0

    def publish() -> dict[str, Any]:
        content = write_results(folder.out, shown, records)
        if on_task_done is not None:
            on_task_done(content)
        return content

    content = publish()
    for record in play_units(pending, run.protocol, run.learners, workers):
        record.update(controller_sha256=run.controllers[record["env_id"]]["sha256"],
                      task_sha256=run.task_digests[record["env_id"]])
        if record["condition"] == "recall":
            record["learner_sha256"] = run.learner_digests[record["env_id"]]
        folder.log(record)
        records.append(record)
        finished += 1
        left[record["env_id"], record["condition"]] -= 1
        if on_progress is not None:
            on_progress(finished, total)
        if left[record["env_id"], record["condition"]] == 0:
            content = publish()
    return content


def rebuild(out: Path) -> dict[str, Any]:
    """``results.json`` of the run in ``out`` made again from its episode log (its tasks, conditions and protocol
    as the folder records them): what a stopped run had played, or a run's table after its code moved on."""
    folder = RunFolder(out)
    saved = json.loads((folder.out / RESULTS_FILE).read_text())
    stored = folder.protocol()
    run = plan(stored, saved["protocol"]["conditions"], env_ids=list(saved["tasks"]),
               learners=stored_learners(saved["protocol"].get("learners")))
    return write_results(folder.out, run, folder.episodes())


def write_results(out: Path, run: Plan, records: list[dict[str, Any]]) -> dict[str, Any]:
    """``run``'s table over ``records`` into ``out/results.json`` and MIKASA's own result layout; the table."""
    content = results(run, records)
    (Path(out) / RESULTS_FILE).write_text(json.dumps(content, indent=2) + "\n")
    write_mikasa_results(Path(out), content, records)
    return content


__all__ = ["CONDITIONS", "Plan", "Protocol", "RunFolder", "Unit", "controller_digest", "controller_record", "cue_label", "done_units",
           "learners_landed", "plan", "play_units", "rebuild", "results", "run_benchmark", "widened",
           "write_results"]
