#!/usr/bin/env bash
# Train detectors on one CUDA machine within a fixed wall-clock deadline, all runs side by side.
# The networks are small, so one GPU holds them all and the CPU cores that decode and augment are
# what limits them: the cores are shared out between the runs as loader workers.
#
#   scripts/train_on_gpu.sh RESULT_DIR [DEADLINE_S]
#
# $RUNS lists the runs as TASK:CONFIG (default: the long runs local_wide_long and global_wide_long).
# A run with a committed checkpoint (checkpoints/CONFIG/last.pt) resumes it and stops when its
# time is up (--stop-after-s), so GPU and CPU sessions add up; copy RESULT's runs/CONFIG/last.pt
# back there and commit it. A run without one starts afresh; one whose config sets
# train.max_wall_s (the *_gpu.yaml ones) has its schedule squeezed into the time it gets.
# Phases, each logged with its elapsed time, after every run of $RUNS is checked (exit 2 and one
# line for a bad one, before anything starts):
#   1. smoke: two steps of each task on one synthetic scene, so a broken set-up fails in seconds
#      instead of after the data preparation;
#   2. data: decode the Halmstad clips and render the synthetic scenes into the cache
#      (all cores; $GLDT_HALMSTAD names the clips when they are not in ../shared);
#   3. train: the runs in parallel, each given what is left of DEADLINE_S (default 540) minus a
#      reserve for its last validation and the packing;
#   4. pack: RESULT_DIR/<config>.tar.gz per run (best.pt, last.pt, log.csv, curves.png, stdout).
# $DEVICE (default cuda) and $CONFIGS (default src/gldt_core/configs/train) let the script be
# tried on a CPU with shrunken configs of the same names.
# With the `device` tool: scripts/gpu_bundle.sh pack (the clips into the checkout, what training
# does not need out of it), then run(command="export GLDT_HALMSTAD=$PWD/.gpu_data/halmstad-visible;
# bash scripts/train_on_gpu.sh $OUT 480", carry=[".gpu_data"], timeout_s=560), then
# scripts/gpu_bundle.sh restore, and copy each run's last.pt back to checkpoints/CONFIG/.
# Export a checkpoint afterwards on any machine: gldt export runs/global_gpu/best.pt --out ...
set -euo pipefail
result=${1:?usage: scripts/train_on_gpu.sh RESULT_DIR [DEADLINE_S]}
deadline=${2:-540}
py=${PYTHON:-python3}
export PYTHONPATH="$PWD/src${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1 OMP_NUM_THREADS=1
configs=${CONFIGS:-src/gldt_core/configs/train}
device=${DEVICE:-cuda}
read -r -a runs <<<"${RUNS:-local:local_wide_long global:global_wide_long}"
start=$SECONDS
say() { echo "[train_on_gpu +$((SECONDS - start)) s] $*"; }

# Every run checked before anything starts: TASK:CONFIG, the config readable, and whether its
# schedule is squeezed into the time it gets (train.max_wall_s set) or counted in steps.
if ((${#runs[@]} == 0)); then
    echo "train_on_gpu: RUNS names no run (expected TASK:CONFIG ...)" >&2
    exit 2
fi
declare -A squeezed=()
for run in "${runs[@]}"; do
    task=${run%%:*} name=${run#*:}
    if [[ $run != *:* || ! $task =~ ^(global|local)$ || -z $name ]]; then
        echo "train_on_gpu: bad run '$run' in RUNS (expected global:CONFIG or local:CONFIG)" >&2
        exit 2
    fi
    squeezed[$name]=$("$py" -c "
import sys
from gldt_core.training.train import load_config
try:
    print(int(float(load_config('$configs/$name.yaml')['train']['max_wall_s']) > 0))
except (OSError, ValueError) as error:
    sys.exit(f'train_on_gpu: run $run: {error}')
") || exit 2
done
mkdir -p "$result" runs

say "smoke: $device steps of both tasks"
DEVICE=$device "$py" - <<'PY'
import os

from gldt_core.training.train import DEFAULTS, merge_config, train

for task in ("global", "local"):
    model = {"channels": [4, 8, 8, 16, 16], "depth": 1, "num_classes": 3, "reg_max": 8, "head_levels": [2, 3]}
    model.update({"dual_frame": True, "stff_levels": [2], "stff_windows": [4]} if task == "global" else {"dual_frame": False})
    config = merge_config(DEFAULTS, {
        "model": model,
        "data": {"cache_dir": "/tmp/gldt-smoke", "use_real": False, "real_validation": False, "synthetic_val_scenes": 1,
                 "synthetic_scenes": 1, "synthetic_frames": 16, "synthetic_frame_step": 8, "val_max_images": 2, "input_size": [128, 128],
                 "val_size": [128, 128], "roi": 150, "val_roi": 150},
        "train": {"epochs": 1, "batch_size": 2, "steps_per_epoch": 2, "device": os.environ["DEVICE"], "loader_workers": 2},
    })
    train(task, config, out_dir=f"/tmp/gldt-smoke/{task}", progress=False)
PY

cores=$(env -u OMP_NUM_THREADS nproc)  # the cores this process may use; nproc honours OMP_NUM_THREADS
# One data build per task: the runs of a task share its cache (same clips, steps and scales).
declare -A first_config=()
for run in "${runs[@]}"; do
    [[ -n ${first_config[${run%%:*}]:-} ]] || first_config[${run%%:*}]=${run#*:}
done
for task in "${!first_config[@]}"; do
    name=${first_config[$task]}
    say "data: $task caches ($name) with $cores workers"
    "$py" -c "
from gldt_core.training.train import build_datasets, load_config
config = load_config('$configs/$name.yaml')
config['data']['load_workers'] = $cores
train_ds, val_ds, info = build_datasets('$task', config)
print('$task:', len(train_ds), 'training pairs (', info['synthetic_train_pairs'], 'synthetic),', len(val_ds), 'validation')
"
done

budget=$((deadline - (SECONDS - start) - 45))
if ((budget < 60)); then
    say "only ${budget} s left for training: giving up"
    exit 1
fi
workers=$(((cores - ${#runs[@]}) / ${#runs[@]}))
workers=$((workers < 1 ? 1 : workers))
say "train: ${#runs[@]} runs, ${budget} s and $workers loader workers each"
pids=()
for run in "${runs[@]}"; do
    task=${run%%:*} name=${run#*:}
    mkdir -p "runs/$name"
    if ((squeezed[$name])); then
        session=(--max-wall-s "$budget")
    else
        session=(--stop-after-s "$budget")
        if [[ -f checkpoints/$name/last.pt ]]; then
            session+=(--resume "checkpoints/$name/last.pt")
            say "$name: resumes checkpoints/$name/last.pt"
        fi
    fi
    "$py" -m gldt_core train "$task" --config "$configs/$name.yaml" --out "runs/$name" "${session[@]}" \
        --device "$device" --workers "$workers" --no-progress >"runs/$name/stdout.txt" 2>&1 &
    pids+=($!)
done
failed=0
for pid in "${pids[@]}"; do
    wait "$pid" || failed=1
done
for run in "${runs[@]}"; do
    name=${run#*:}
    say "$name: $(grep -E 'epoch [0-9]+:' "runs/$name/stdout.txt" | tail -1)"
    tail -n 3 "runs/$name/stdout.txt"
    tar -czf "$result/$name.tar.gz" "runs/$name"
done
say "done (failed=$failed)"
exit "$failed"
