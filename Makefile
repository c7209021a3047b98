# One-command set-up: each target creates .venv (Python 3.12) and installs the pinned stack on first use.
# PYTHON=/path/to/python3.12 overrides the interpreter; by default the first Python 3.12 found on PATH
# or among pyenv's versions.
VENV ?= .venv
PY := $(VENV)/bin/python
PYTEST_ARGS ?=
RENDERER ?= .renderer
is_py312 = $(shell $(1) -c 'import sys; assert sys.version_info[:2] == (3, 12)' >/dev/null 2>&1 && echo yes)
PYTHON ?= $(firstword $(foreach p,python3.12 $(wildcard $(HOME)/.pyenv/versions/3.12*/bin/python3.12),$(if $(call is_py312,$(p)),$(p))))

.PHONY: install renderer train test docs bench main-job-sweep controller controller-objects controller-camera controller-mikasa controller-multitask learner-multitask learners-long-horizon tables-privileged tables-camera tables-learned clean

$(VENV)/.installed: setup.cfg pyproject.toml constraints.txt
	@test -n "$(PYTHON)" || { echo "error: no Python 3.12 found; install one (e.g. pyenv install 3.12) or pass PYTHON=/path/to/python3.12" >&2; exit 1; }
	# an existing environment is updated in place: removing it would break every job running from it
	[ -x $(PY) ] || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	# torch 2.11.0 from the package index: the same build runs on the CPU and on CUDA 13 GPUs
	$(PY) -m pip install --quiet -c constraints.txt torch==2.11.0 -e ".[test,openpi,ray,tune]"
	# openpi-client (and openpi-server, which needs it) pin numpy<2 but work with numpy 2: install them without their pins
	$(PY) -m pip install --quiet --no-deps openpi-client==0.1.2 openpi-server==0.1.0
	# MIKASA-Robo-VLA pins Python < 3.12 and mani_skill 3.0.0b15 but runs on this stack: install it without its pins
	$(PY) -m pip install --quiet --no-deps --ignore-requires-python mikasa-robo-suite==1.0.0
	touch $@

# Mesa 25 lavapipe, a software Vulkan driver SAPIEN can render with on a CPU (render_backend="cpu")
$(RENDERER)/lvp_icd.json: scripts/install_lavapipe.sh
	bash scripts/install_lavapipe.sh $(RENDERER)

install: $(VENV)/.installed

renderer: $(RENDERER)/lvp_icd.json

train: install renderer
	$(VENV)/bin/sb3-memret train recall --report

# the documentation's stack too: the suite builds the guide (tests/test_docs.py) rather than skip it
# the suite in TEST_WORKERS processes (pytest-xdist): 2 fills a 2-core CPU; 0 runs it in this process
TEST_WORKERS ?= 2
test: install renderer $(VENV)/.docs-installed
	$(PY) -m pytest -n $(TEST_WORKERS) $(PYTEST_ARGS)

# The documentation site (docs/: Sphinx and MyST): the guides, the API reference from the docstrings, the results
# pages generated from benchmarks/**/results.json. Warnings are errors. Open docs/_build/html/index.html.
$(VENV)/.docs-installed: docs/requirements.txt $(VENV)/.installed
	$(PY) -m pip install --quiet -c constraints.txt -r docs/requirements.txt
	touch $@

docs: install $(VENV)/.docs-installed
	$(PY) -m sphinx -W --keep-going -q -b html docs docs/_build/html
	@echo "docs/_build/html/index.html"

# Rebuild the drawer's shipped state controller (`--controller learned-state`): 240 expert episodes (half with action
# noise, clean labels), then behaviour cloning; about 8 minutes on 2 CPU cores.
STAGE1 ?= runs/stage1
# a literal comma, for $(subst)
comma := ,
SHIPPED := sb3_memret/controllers/checkpoints/drawer-learned
controller: install
	rm -rf $(STAGE1)
	$(VENV)/bin/sb3-memret demos --episodes 240 --out $(STAGE1)/demos
	$(VENV)/bin/sb3-memret finetune $(STAGE1)/demos --config $(SHIPPED)/recipe.yml --out $(STAGE1)/policy
	mkdir -p $(SHIPPED)
	cp $(STAGE1)/policy/config.json $(STAGE1)/policy/model.safetensors $(STAGE1)/policy/train_log.csv $(SHIPPED)/

# The learned controller of several objects (`--controller learned-objects`): three objects of the training set
# in the drawers, the prompts naming the target; as long again as `controller`.
SHIPPED_OBJECTS := sb3_memret/controllers/checkpoints/drawer-objects-learned
controller-objects: install
	rm -rf $(STAGE1)-objects
	$(VENV)/bin/sb3-memret demos --episodes 240 --objects train --n-objects 3 --out $(STAGE1)-objects/demos
	$(VENV)/bin/sb3-memret finetune $(STAGE1)-objects/demos --config $(SHIPPED_OBJECTS)/recipe.yml \
		--out $(STAGE1)-objects/policy
	mkdir -p $(SHIPPED_OBJECTS)
	cp $(STAGE1)-objects/policy/config.json $(STAGE1)-objects/policy/model.safetensors \
		$(STAGE1)-objects/policy/train_log.csv $(SHIPPED_OBJECTS)/

# The camera-reading learned controller of the drawer (`--controller learned`): 480 expert episodes rendered at their
# decision frames only (both cameras, stored at 128x128, the light Panda the drawer draws; the checkpoint records the
# robot and refuses another), then a policy on the hand's state and the cameras through frozen EfficientNet-Lite0
# features, its perception head trained on the simulator's labels. Demos ~13 min, finetune ~24 min on an idle 2-core
# CPU. Finetune seed 1 ships: on fresh placements (rollout --seed 2000000, 30 a layer) it gave 97 / 90 / 87% with the
# oracle fact, seed 0 87 / 83 / 83%.
SHIPPED_CAMERA := sb3_memret/controllers/checkpoints/drawer-camera
controller-camera: install renderer
	rm -rf $(STAGE1)-camera
	$(VENV)/bin/sb3-memret demos --episodes 480 --render-backend cpu --image-size 128 --out $(STAGE1)-camera/demos
	$(VENV)/bin/sb3-memret finetune $(STAGE1)-camera/demos --config $(SHIPPED_CAMERA)/recipe.yml \
		--out $(STAGE1)-camera/policy
	mkdir -p $(SHIPPED_CAMERA)
	cp $(STAGE1)-camera/policy/config.json $(STAGE1)-camera/policy/model.safetensors \
		$(STAGE1)-camera/policy/train_log.csv $(SHIPPED_CAMERA)/

# The camera-reading learned controller of a MIKASA task (`--task $(MIKASA_TASK) --controller learned-task`):
# $(MIKASA_EPISODES) expert episodes with every control step kept (MIKASA renders its 128x128 cameras at every step
# anyway), then the policy on joints, hand pose and both cameras by the task's recipe (its shipped checkpoint's
# recipe.yml, else zoo_configs/finetune_learned.yml). MIKASA_DAGGER=N adds a DAgger round: N episodes (seeds after the
# expert's) played by a first policy (MIKASA_STEPS steps, default the recipe's) and labelled by the expert, then the
# recipe's policy on both datasets. MIKASA_SET='--set KEY=VALUE ...' changes the recipe for both finetunes.
MIKASA_TASK ?= RememberColor3-VLA-v0
MIKASA_EPISODES ?= 400
MIKASA_DAGGER ?= 0
MIKASA_STEPS ?=
MIKASA_SET ?=
MIKASA_SHIPPED = sb3_memret/controllers/checkpoints/$(MIKASA_TASK)-camera
MIKASA_RECIPE ?= $(firstword $(wildcard $(MIKASA_SHIPPED)/recipe.yml) zoo_configs/finetune_learned.yml)
MIKASA_RUN = $(STAGE1)-$(MIKASA_TASK)
controller-mikasa: install renderer
	rm -rf $(MIKASA_RUN)
	$(VENV)/bin/sb3-memret demos --task $(MIKASA_TASK) --episodes $(MIKASA_EPISODES) --frames every --out $(MIKASA_RUN)/demos
	$(VENV)/bin/sb3-memret finetune $(MIKASA_RUN)/demos --task $(MIKASA_TASK) --config $(MIKASA_RECIPE) $(MIKASA_SET) \
		$(if $(filter-out 0,$(MIKASA_DAGGER)),$(if $(MIKASA_STEPS),--set training.steps=$(MIKASA_STEPS))) \
		--out $(MIKASA_RUN)/policy
	if [ $(MIKASA_DAGGER) -gt 0 ]; then \
		$(VENV)/bin/sb3-memret demos --task $(MIKASA_TASK) --episodes $(MIKASA_DAGGER) --frames every \
			--seed $$((100000 + $(MIKASA_EPISODES))) --learner learned:$(MIKASA_RUN)/policy --out $(MIKASA_RUN)/dagger && \
		mv $(MIKASA_RUN)/policy $(MIKASA_RUN)/policy-expert && \
		$(VENV)/bin/sb3-memret finetune $(MIKASA_RUN)/demos $(MIKASA_RUN)/dagger --task $(MIKASA_TASK) \
			--config $(MIKASA_RECIPE) $(MIKASA_SET) --out $(MIKASA_RUN)/policy; \
	fi
	mkdir -p $(MIKASA_SHIPPED)
	cp $(MIKASA_RUN)/policy/config.json $(MIKASA_RUN)/policy/model.safetensors $(MIKASA_RUN)/policy/train_log.csv \
		$(MIKASA_SHIPPED)/
	[ $(MIKASA_RECIPE) -ef $(MIKASA_SHIPPED)/recipe.yml ] || cp $(MIKASA_RECIPE) $(MIKASA_SHIPPED)/recipe.yml

# The one camera controller across the MIKASA tasks the scripted experts run (`--controller learned` on each; finetune
# --tasks): every short-split task whose success is touching the object a fact names, the others the experts run
# (MULTITASK_MORE_TASKS), and SeqOfColors3, whose prompt also says which cubes were touched (progress as memory); the
# prompt tells the tasks apart. Wider camera heads, the object pointer,
# and the harness's 7-D proprioception alone (the recipe's state: harness), so its benchmark rows are a protocol entry.
# Data in resumable chunks of 50 (scripts/record_task_demos.sh: decision frames, the cameras rendering only there; a
# rerun records only the missing chunks; keep the counts multiples of 50; `JOBS=2 make controller-multitask` records two
# chunks at a time): $(MULTITASK_EPISODES) expert episodes of each
# task, then $(MULTITASK_ONPOLICY) more played by the task's own camera controller (`learned-task`) where one
# ships, the expert labelling; a first policy on them (kept when the target runs again: scripts/finetune_task_demos.sh);
# a DAgger round of $(MULTITASK_DAGGER) episodes of each played by the first policy; $(MULTITASK_EXTRA) more expert
# episodes of the tasks the first policy won under 60% of when told the true fact, in the DAgger round's first chunks
# (MULTITASK_EXTRA_TASKS); $(MULTITASK_PROGRESS) expert episodes of the progress tasks, ended after
# $(MULTITASK_PROGRESS_STEPS) steps; the shipped policy on all of it. MULTITASK_PROMPT_MIX sets the recordings'
# prompt kinds (demos --prompt-mix; empty: its default, which the shipped policy was built with). On an idle 2-core CPU a chunk takes about 75 s
# (SeqOfColors3's 10 minutes) and the finetunes 2-5 steps/s after the frozen trunk's features (kept for later
# finetunes): about 7 hours in all for the twenty tasks the shipped checkpoint serves, which was built in stages,
# with the same final training on 450-800 episodes a task and 200 of SeqOfColors3 (lab/2026-11-30-one-camera-controller-across-twenty-tasks-the-added lists each task's data).
MULTITASK_TOUCH_TASKS ?= RememberColor3-VLA-v0,RememberShape3-VLA-v0,RememberColor5-VLA-v0,TakeItBack-VLA-v0,RememberShape5-VLA-v0,FindImposterColor3-VLA-v0,RememberShapeAndColor3x2-VLA-v0,RememberColor9-VLA-v0,FindImposterShape3-VLA-v0,RememberShapeAndColor3x3-VLA-v0,FindImposterColor5-VLA-v0,RememberShape9-VLA-v0,FindImposterShapeAndColor3x2-VLA-v0,RememberShapeAndColor5x3-VLA-v0,FindImposterColor9-VLA-v0,FindImposterShape5-VLA-v0,FindImposterShapeAndColor3x3-VLA-v0,FindImposterShape9-VLA-v0,FindImposterShapeAndColor5x3-VLA-v0
MULTITASK_EXTRA_TASKS ?= RememberShape3-VLA-v0,TakeItBack-VLA-v0,RememberShape5-VLA-v0,RememberShapeAndColor3x2-VLA-v0,RememberColor9-VLA-v0,FindImposterShape3-VLA-v0,RememberShapeAndColor3x3-VLA-v0,RememberShape9-VLA-v0,FindImposterShapeAndColor3x2-VLA-v0,RememberShapeAndColor5x3-VLA-v0,FindImposterColor9-VLA-v0,FindImposterShape5-VLA-v0,FindImposterShapeAndColor3x3-VLA-v0,FindImposterShape9-VLA-v0,FindImposterShapeAndColor5x3-VLA-v0,RotateLenientPos-VLA-v0,RotateLenientPosNeg-VLA-v0,RotateStrictPos-VLA-v0,RotateStrictPosNeg-VLA-v0,TimedTransferEasy-VLA-v0
# the short tasks whose success is not a touch (intercept, rotate, count and press, gather, act on time): expert
# episodes and the DAgger round as the touch tasks', no on-policy stage (no camera controller of their own ships)
MULTITASK_MORE_TASKS ?= InterceptSlow-VLA-v0,InterceptMedium-VLA-v0,InterceptFast-VLA-v0,InterceptGrabSlow-VLA-v0,InterceptGrabMedium-VLA-v0,InterceptGrabFast-VLA-v0,RotateLenientPos-VLA-v0,RotateLenientPosNeg-VLA-v0,RotateStrictPos-VLA-v0,RotateStrictPosNeg-VLA-v0,BlinkCountButtonPressEasy-VLA-v0,BlinkCountButtonPressMedium-VLA-v0,GatherAndRecall1-VLA-v0,TimedTransferEasy-VLA-v0
MULTITASK_PROGRESS_TASKS ?= SeqOfColors3-VLA-v0
MULTITASK_EXPERT_TASKS = $(MULTITASK_TOUCH_TASKS)$(if $(MULTITASK_MORE_TASKS),$(comma)$(MULTITASK_MORE_TASKS))
MULTITASK_TASKS = $(MULTITASK_EXPERT_TASKS)$(if $(MULTITASK_PROGRESS_TASKS),$(comma)$(MULTITASK_PROGRESS_TASKS))
MULTITASK_EPISODES ?= 200
MULTITASK_ONPOLICY ?= 100
MULTITASK_STEPS ?= 5000
MULTITASK_RECIPE ?= sb3_memret/controllers/checkpoints/mikasa-multitask-camera/recipe.yml
MULTITASK_DAGGER ?= 150
MULTITASK_EXTRA ?= 200
MULTITASK_PROGRESS ?= 200
MULTITASK_PROGRESS_STEPS ?= 160
MULTITASK_PROMPT_MIX ?=
MULTITASK_RUN = $(STAGE1)-multitask
SHIPPED_MULTITASK := sb3_memret/controllers/checkpoints/mikasa-multitask-camera
touch_tasks = $(subst $(comma), ,$(MULTITASK_TOUCH_TASKS))
expert_tasks = $(subst $(comma), ,$(MULTITASK_EXPERT_TASKS))
controller-multitask: export PROMPT_MIX = $(MULTITASK_PROMPT_MIX)
controller-multitask: install renderer
	scripts/record_task_demos.sh $(MULTITASK_RUN)/demos $(MULTITASK_EPISODES) $(expert_tasks)
	for task in $(touch_tasks); do \
		own=$$($(PY) -c "from sb3_memret.controllers.shipped import SHIPPED; print('learned-task' if ('$$task', 'learned-task') in SHIPPED else '')") && \
		LEARNER=$$own scripts/record_task_demos.sh $(MULTITASK_RUN)/demos \
			$$(($(MULTITASK_EPISODES) + $(MULTITASK_ONPOLICY))) $$task || exit 1; \
	done
	scripts/finetune_task_demos.sh $(MULTITASK_RUN)/demos $(MULTITASK_RUN)/policy-first $(MULTITASK_EXPERT_TASKS) \
		--config $(MULTITASK_RECIPE) --set training.steps=$(MULTITASK_STEPS)
	LEARNER=learned:$(MULTITASK_RUN)/policy-first SEED=$$((100000 + $(MULTITASK_EPISODES) + $(MULTITASK_ONPOLICY))) \
		scripts/record_task_demos.sh $(MULTITASK_RUN)/dagger $(MULTITASK_DAGGER) $(expert_tasks)
	SEED=$$((100000 + $(MULTITASK_EPISODES) + $(MULTITASK_ONPOLICY) + $(MULTITASK_DAGGER))) scripts/record_task_demos.sh \
		$(MULTITASK_RUN)/extra $(MULTITASK_EXTRA) $(subst $(comma), ,$(MULTITASK_EXTRA_TASKS))
	$(if $(MULTITASK_PROGRESS_TASKS),MAX_STEPS=$(MULTITASK_PROGRESS_STEPS) scripts/record_task_demos.sh \
		$(MULTITASK_RUN)/progress $(MULTITASK_PROGRESS) $(subst $(comma), ,$(MULTITASK_PROGRESS_TASKS)))
	scripts/finetune_task_demos.sh '$(MULTITASK_RUN)/demos?,$(MULTITASK_RUN)/dagger?,$(MULTITASK_RUN)/extra?,$(MULTITASK_RUN)/progress?' \
		$(MULTITASK_RUN)/policy $(MULTITASK_TASKS) --config $(MULTITASK_RECIPE)
	if $(PY) -c "import sys; from sb3_memret.controllers.shipped import MULTITASK_TASKS as t; \
			sys.exit(set(t) != set('$(MULTITASK_TASKS)'.split(',')))"; then \
		mkdir -p $(SHIPPED_MULTITASK) && cp $(MULTITASK_RUN)/policy/config.json \
			$(MULTITASK_RUN)/policy/model.safetensors $(MULTITASK_RUN)/policy/train_log.csv $(SHIPPED_MULTITASK)/; \
	else \
		echo "not the shipped controller's tasks, so not copied into the package: --controller learned:$(MULTITASK_RUN)/policy"; \
	fi

# Rebuild the shipped memory learner across the short split (the recall condition's default in `sb3-memret benchmark
# mikasa`): one learner on every short-split task that runs here, the zoo's `multitask` section (24,576 decisions),
# the scripted experts as the frozen controller; about 2 hours on a 2-core CPU. An interrupted run resumes.
LEARNER_RUN ?= runs/learner-multitask
SHIPPED_LEARNER := sb3_memret/benchmark/checkpoints/mikasa-short-learner

learner-multitask: install renderer
	$(VENV)/bin/sb3-memret train recall --tasks mikasa:short --controller scripted --seed 0 --out $(LEARNER_RUN) \
		--eval-every 12 --no-progress $$([ -f $(LEARNER_RUN)/config.yml ] && echo --resume)
	mkdir -p $(SHIPPED_LEARNER)
	cp $(LEARNER_RUN)/final_model.zip $(LEARNER_RUN)/config.yml $(LEARNER_RUN)/summary.json $(SHIPPED_LEARNER)/

# The memory learners of the tasks the shipped learner does not serve (TimedTransferEasy; GatherAndRecall1 and
# BlinkCount Medium / Easy, where it retrieves decoys: 2, 4 and 8 of 10 at development seeds; the medium and long
# families), one `train recall` run per task on its zoo section into LEARNERS_DIR, cheapest first; a finished task is
# kept, an interrupted one resumes. A -Long variant plays its short task's. The tables' recall looks there first.
# The folder is in the repository (each finished learner committed: its model, config, summary and evaluations; the
# checkpoints and logs are ignored), so that the tables' recall cells are read and replayed on any checkout.
# A run ends early once LEARNERS_STOP_PATIENCE held-out evaluations in a row retrieve the true memory greedily at
# LEARNERS_STOP_AT (the zoo budgets are for the hardest seed; TimedTransferEasy was at 100% from round 5 of 12).
LEARNERS_DIR ?= benchmarks/learners-long-horizon
LEARNERS_STOP_AT ?= 1.0
LEARNERS_STOP_PATIENCE ?= 2
space := $(subst ,, )
LONG_HORIZON_LEARNER_TASKS ?= TimedTransferEasy-VLA-v0,GatherAndRecall1-VLA-v0,BlinkCountButtonPressMedium-VLA-v0,\
BlinkCountButtonPressEasy-VLA-v0,BunchOfColors3-VLA-v0,SeqOfColors3-VLA-v0,ChainOfColors3-VLA-v0,\
BlinkCountButtonPressHard-VLA-v0,TimedTransferMedium-VLA-v0,TimedTransferHard-VLA-v0,TimedTransferEasy-Long-VLA-v0,\
GatherAndRecall3-VLA-v0,GatherAndRecall5-VLA-v0,TraceShapeEasy-VLA-v0,TraceShapeMedium-VLA-v0,TraceShapeHard-VLA-v0,\
BatteriesCheckerEasy-3-VLA-v0,BunchOfColors5-VLA-v0,SeqOfColors5-VLA-v0,ChainOfColors5-VLA-v0,BunchOfColors7-VLA-v0,\
SeqOfColors7-VLA-v0,ChainOfColors7-VLA-v0,TraceShapeSeqEasy-VLA-v0,TraceShapeSeqMedium-VLA-v0,TraceShapeSeqHard-VLA-v0,\
GatherAndRecall7-VLA-v0,GatherAndRecall9-VLA-v0,BatteriesCheckerEasy-6-VLA-v0,BatteriesCheckerHard-3-VLA-v0,\
BatteriesCheckerHard-6-VLA-v0

learners-long-horizon: install renderer
	$(VENV)/bin/sb3-memret benchmark learners --tasks $(subst $(space),,$(LONG_HORIZON_LEARNER_TASKS)) \
		--eval-episodes 20 --stop-at-greedy $(LEARNERS_STOP_AT) --stop-patience $(LEARNERS_STOP_PATIENCE) --out $(LEARNERS_DIR)

# The benchmark's tables in benchmarks/mikasa/ (commit each folder as it grows: a table plays for many hours, a rerun
# plays only the cells still missing, and a cell played by other code, controller or learner is played again).
# tables-privileged: the scripted experts, a privileged upper bound, on each split (TABLE_SPLITS) at the protocol
# seeds; tables-camera: the experts' motion on what the cameras show (scripted-camera, the harness's inputs alone),
# the ceiling of a camera-only controller, likewise; tables-learned: the shipped camera controller on the harness's
# inputs alone, a protocol entry, on the short split at development seeds, then at the protocol seeds. Recall plays
# each task's learner from TABLE_LEARNERS, the first that serves it (make learners-long-horizon's, then the shipped
# one across the short split); a task none serves yet has its recall cell refused, and a rerun plays it.
TABLE_SPLITS ?= short medium long
TABLE_CONDITIONS ?= none,oracle,wrong,recall
TABLE_LEARNERS ?= $(LEARNERS_DIR) shipped
TABLES ?= benchmarks/mikasa
tables-privileged: install renderer
	set -e; for split in $(TABLE_SPLITS); do \
		$(VENV)/bin/sb3-memret benchmark mikasa --split $$split --controller scripted --conditions $(TABLE_CONDITIONS) \
			$(addprefix --learners ,$(TABLE_LEARNERS)) --seeds protocol --no-progress --out $(TABLES)/$$split-scripted-protocol; \
	done

tables-camera: install renderer
	set -e; for split in $(TABLE_SPLITS); do \
		$(VENV)/bin/sb3-memret benchmark mikasa --split $$split --controller scripted-camera \
			--conditions $(TABLE_CONDITIONS) $(addprefix --learners ,$(TABLE_LEARNERS)) --seeds protocol --no-progress \
			--out $(TABLES)/$$split-scripted-camera-protocol; \
	done

tables-learned: install renderer
	set -e; for seeds in dev protocol; do \
		$(VENV)/bin/sb3-memret benchmark mikasa --split short --controller learned --conditions $(TABLE_CONDITIONS) \
			$(addprefix --learners ,$(TABLE_LEARNERS)) --seeds $$seeds --no-progress --out $(TABLES)/short-learned-$$seeds; \
	done

bench: install
	$(PY) scripts/bench_env.py

# The main job at training seeds 0-4 (SWEEP_SEEDS), each as `make train` runs it (--report), into runs/main-job/seedS;
# a finished seed is skipped and an unfinished one resumed. Each run's small files (config, evaluations, summary with
# its baselines and time split, progress log, curves, report) are copied to benchmarks/main-job/seedS, from which the
# docs' results page draws the sweep's table, beside the folder's about.md (written by hand: what the controller
# reads, on which seeds the settings were chosen). About 8 minutes a seed on a 2-core CPU.
SWEEP_SEEDS ?= 0 1 2 3 4
SWEEP_RUNS ?= runs/main-job
SWEEP_OUT ?= benchmarks/main-job
SWEEP_FILES := config.yml run.json summary.json evaluations.jsonl progress.csv learning_curves.png report.md
main-job-sweep: install renderer
	set -e; for seed in $(SWEEP_SEEDS); do \
		run=$(SWEEP_RUNS)/seed$$seed; \
		if [ ! -f $$run/report.md ]; then \
			$(VENV)/bin/sb3-memret train recall --report --no-progress --seed $$seed --out $$run \
				$$([ -f $$run/config.yml ] && echo --resume); \
		fi; \
		mkdir -p $(SWEEP_OUT)/seed$$seed; \
		for file in $(SWEEP_FILES); do cp $$run/$$file $(SWEEP_OUT)/seed$$seed/; done; \
	done
	$(PY) scripts/seed_sweep.py $(addprefix $(SWEEP_OUT)/seed,$(SWEEP_SEEDS))

clean:
	rm -rf $(VENV) $(RENDERER) runs
