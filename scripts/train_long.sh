#!/usr/bin/env bash
# Go on with the long training runs on this machine's CPU for a while, then put their state back
# where the next session (CPU or GPU) resumes it.
#
#   scripts/train_long.sh SECONDS [CONFIG ...]     (default: local_wide_long global_wide_long)
#
# From the checkout's root; $CONFIGS (default src/gldt_core/configs/train) holds the configs.
# Each run resumes checkpoints/CONFIG/last.pt (or starts afresh where there is none), trains on
# one thread into runs/CONFIG until its next epoch would end past SECONDS, and then copies its
# last.pt and log.csv back to checkpoints/CONFIG/; commit those. Runs go side by side, one core
# each; start it in the background (nohup ... &) and work beside it. Stopped early (kill), a run
# loses only the epoch in progress: runs/CONFIG/ holds the last whole one, to copy back by hand.
set -euo pipefail
seconds=${1:?usage: scripts/train_long.sh SECONDS [CONFIG ...]}
shift
if (($# > 0)); then configs=("$@"); else configs=(local_wide_long global_wide_long); fi
py=${PYTHON:-.venv/bin/python}
configs_dir=${CONFIGS:-src/gldt_core/configs/train}
export PYTHONPATH="$PWD/src${PYTHONPATH:+:$PYTHONPATH}"
pids=()
for name in "${configs[@]}"; do
    config=$configs_dir/$name.yaml
    task=$("$py" -c "
from gldt_core.training.train import load_config
print('global' if load_config('$config')['model'].get('dual_frame') else 'local')")
    resume=()
    [[ -f checkpoints/$name/last.pt ]] && resume=(--resume "checkpoints/$name/last.pt")
    mkdir -p "runs/$name"
    echo "train_long: $name ($task) ${resume[*]:-from scratch}, $seconds s; log in runs/$name/stdout.txt"
    "$py" -m gldt_core train "$task" --config "$config" --out "runs/$name" "${resume[@]}" \
        --stop-after-s "$seconds" --no-progress >>"runs/$name/stdout.txt" 2>&1 &
    pids+=($!)
done
failed=0
for i in "${!pids[@]}"; do
    name=${configs[$i]}
    if wait "${pids[$i]}"; then
        mkdir -p "checkpoints/$name"
        cp "runs/$name/last.pt" "runs/$name/log.csv" "checkpoints/$name/"
        echo "train_long: $name: $(grep -E 'epoch [0-9]+:' "runs/$name/stdout.txt" | tail -1)"
    else
        echo "train_long: $name failed; see runs/$name/stdout.txt" >&2
        failed=1
    fi
done
exit "$failed"
