#!/usr/bin/env bash
# Make this checkout fit what the `device` tool sends to a GPU machine (64 MiB: tracked files,
# untracked ones git does not ignore, and the paths named in `carry`), then put it back.
#
#   scripts/gpu_bundle.sh pack      # before the call: run(command=..., carry=[".gpu_data"])
#   scripts/gpu_bundle.sh restore   # after it, always
#
# pack copies the annotations of every Halmstad clip and the videos of the training and `val`
# clips (what training reads; the split follows the annotations, so it is the same there) into
# .gpu_data/halmstad-visible, and moves what training does not need (the sample bags, the
# shipped ONNX models, checkpoints that are not resumed there) into .gpu_stash/. Both folders
# are ignored through .git/info/exclude. The command on the machine then starts with
#   export GLDT_HALMSTAD=$PWD/.gpu_data/halmstad-visible; scripts/train_on_gpu.sh $OUT 480
set -euo pipefail
cd "$(git rev-parse --show-toplevel)"
py=${PYTHON:-.venv/bin/python}
stashed=(bags src/gldt_core/models checkpoints/second_stage.pt checkpoints/local_wide_gpu checkpoints/global_wide_gpu)
limit=$((64 * 1024 * 1024))

ignore() {
    grep -qxF "/$1/" .git/info/exclude 2>/dev/null || echo "/$1/" >>.git/info/exclude
}

case ${1:-} in
pack)
    mkdir -p .git/info
    ignore .gpu_data
    ignore .gpu_stash
    root=$("$py" -c "from gldt_core.paths import halmstad_root; print(halmstad_root())")
    data=.gpu_data/halmstad-visible
    rm -rf "$data"
    mkdir -p "$data/videos" .gpu_stash
    cp -r "$root/gt" "$data/"
    "$py" -c "
from gldt_core.eval.halmstad_split import halmstad_split
split = halmstad_split('$root')
print('\n'.join(split['train'] + split['val']))
" | while read -r clip; do cp "$root/videos/$clip.mp4" "$data/videos/"; done
    for path in "${stashed[@]}"; do
        if [[ -e $path ]]; then
            mkdir -p ".gpu_stash/$(dirname "$path")"
            mv "$path" ".gpu_stash/$path"
        fi
    done
    sizes=$("$py" - <<'PY'
import os
import subprocess


def size(*options: str) -> int:
    names = subprocess.run(["git", "ls-files", "-z", *options], capture_output=True, check=True).stdout.split(b"\0")
    return sum(os.path.getsize(name) for name in names if name and os.path.isfile(name))


carried = sum(os.path.getsize(os.path.join(d, f)) for d, _, fs in os.walk(".gpu_data") for f in fs)
print(size(), size("--others", "--exclude-standard"), carried)
PY
)
    read -r tracked untracked carried <<<"$sizes"
    total=$((tracked + untracked + carried))
    mib() { echo "$(($1 / 1024 / 1024))"; }
    echo "gpu_bundle: $(mib $total) MiB would travel (tracked $(mib $tracked), untracked $(mib $untracked)," \
        ".gpu_data $(mib $carried); the limit is 64)"
    if ((total > limit)); then
        echo "gpu_bundle: over the limit; stash more (scripts/gpu_bundle.sh restore puts everything back)" >&2
        exit 1
    fi
    ;;
restore)
    for path in "${stashed[@]}"; do
        if [[ -e .gpu_stash/$path ]]; then
            rm -rf "$path"
            mkdir -p "$(dirname "$path")"
            mv ".gpu_stash/$path" "$path"
        fi
    done
    git status --short | head -20
    ;;
*)
    echo "usage: scripts/gpu_bundle.sh pack|restore" >&2
    exit 2
    ;;
esac
