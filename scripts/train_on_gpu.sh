#!/usr/bin/env bash
# Train the shipped detectors on one CUDA machine within a fixed wall-clock deadline:
# AM-YOLO (global_gpu.yaml), its no-STFF ablation (global_nostff_gpu.yaml) and the local model
# (local_gpu.yaml), side by side. The networks are tiny, so one GPU holds all three and the CPU
# cores that decode and augment are what limits them.
#
#   scripts/train_on_gpu.sh RESULT_DIR [DEADLINE_S]
#
# Phases, each logged with its elapsed time:
#   1. smoke: two CUDA steps of each task on one synthetic scene, so a broken set-up fails in
#      seconds instead of after the data preparation;
#   2. data: decode the Halmstad clips and render the synthetic scenes into the cache
#      (all cores; $GLDT_HALMSTAD names the clips when they are not in ../shared);
#   3. train: the three runs in parallel, each given what is left of DEADLINE_S (default 540)
#      minus a reserve for its last validation and the packing;
#   4. pack: runs/*_gpu (checkpoints, log.csv, curves.png, stdout) into RESULT_DIR/runs.tar.gz.
# $DEVICE (default cuda) and $CONFIGS (default src/gldt_core/configs) let the script be tried on a
# CPU with shrunken configs of the same names.
# Export the checkpoints afterwards on any machine: gldt export runs/global_gpu/last.pt --out ...
set -euo pipefail
result=${1:?usage: scripts/train_on_gpu.sh RESULT_DIR [DEADLINE_S]}
deadline=${2:-540}
py=${PYTHON:-python3}
export PYTHONPATH="$PWD/src${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1 OMP_NUM_THREADS=1
configs=${CONFIGS:-src/gldt_core/configs}
device=${DEVICE:-cuda}
start=$SECONDS
mkdir -p "$result" runs
say() { echo "[train_on_gpu +$((SECONDS - start)) s] $*"; }

say "smoke: $device steps of both tasks"
DEVICE=$device "$py" - <<'PY'
import os

from gldt_core.training.train import DEFAULTS, _merge, train

for task in ("global", "local"):
    model = {"channels": [4, 8, 8, 16, 16], "depth": 1, "num_classes": 3, "reg_max": 8, "head_levels": [2, 3]}
    model.update({"dual_frame": True, "stff_levels": [2], "stff_windows": [4]} if task == "global" else {"dual_frame": False})
    config = _merge(DEFAULTS, {
        "model": model,
        "data": {"cache_dir": "/tmp/gldt-smoke", "use_real": False, "real_validation": False, "synthetic_val_scenes": 1,
                 "synthetic_scenes": 1, "synthetic_frames": 16, "synthetic_frame_step": 8, "val_max_images": 2, "input_size": [128, 128],
                 "val_size": [128, 128], "roi": 150, "val_roi": 150},
        "train": {"epochs": 1, "batch_size": 2, "steps_per_epoch": 2, "device": os.environ["DEVICE"], "loader_workers": 2},
    })
    train(task, config, out_dir=f"/tmp/gldt-smoke/{task}", progress=False)
PY

nproc_all=$(nproc)
for task_config in global:global_gpu local:local_gpu; do
    task=${task_config%%:*}
    say "data: $task caches with $nproc_all workers"
    "$py" -c "
from gldt_core.training.train import build_datasets, load_config
config = load_config('$configs/${task_config#*:}.yaml')
config['data']['load_workers'] = $nproc_all
train_ds, val_ds, info = build_datasets('$task', config)
print('$task:', len(train_ds), 'training pairs (', info['synthetic_train_pairs'], 'synthetic),', len(val_ds), 'validation')
"
done

budget=$((deadline - (SECONDS - start) - 45))
if ((budget < 60)); then
    say "only ${budget} s left for training: giving up"
    exit 1
fi
say "train: three runs, ${budget} s each"
pids=()
for run in global:global_gpu global:global_nostff_gpu local:local_gpu; do
    task=${run%%:*} name=${run#*:}
    mkdir -p "runs/$name"
    "$py" -m gldt_core train "$task" --config "$configs/$name.yaml" --out "runs/$name" --max-wall-s "$budget" --device "$device" --no-progress \
        >"runs/$name/stdout.txt" 2>&1 &
    pids+=($!)
done
failed=0
for pid in "${pids[@]}"; do
    wait "$pid" || failed=1
done
for name in global_gpu global_nostff_gpu local_gpu; do
    say "$name: $(grep -E 'epoch [0-9]+:' "runs/$name/stdout.txt" | tail -1)"
    tail -n 3 "runs/$name/stdout.txt"
done
say "pack"
tar -czf "$result/runs.tar.gz" runs/global_gpu runs/global_nostff_gpu runs/local_gpu
say "done (failed=$failed)"
exit "$failed"
