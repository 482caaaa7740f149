#!/usr/bin/env bash
# Continue training the panda_cpu recipe on one CUDA GPU, on frames rendered there and then.
#
#   benchmarks/gpu_finetune.sh INIT_CKPT OUT_DIR DATA_DIR SEED NUM RENDER_S TRAIN_S [KEY=VALUE ...]
#
# 1. renders up to NUM new `dream synth` Panda frames (seed SEED, half of them holding an object)
#    into DATA_DIR/train_SEED with one process per core, stopping after RENDER_S seconds (a killed
#    render leaves only complete frames; frames already there are kept), and completes 200
#    held-out frames (seed 2000) for the curve; a render that fails stops the script. With
#    SYNTH_CONFIG=FILE in the environment (e.g. configs/synth/real_world.yaml), half the frames
#    and half the time go to that recipe instead (seed SEED + 1, DATA_DIR/train_<SEED+1>_<name>);
# 2. trains from INIT_CKPT's weights (a checkpoint or an exported .onnx; `none`: the recipe's own
#    start, e.g. a pretrained encoder's ImageNet weights with model.encoder=efficientnet_lite0;
#    fresh optimiser, one-cycle schedule) on every DATA_DIR/train_* folder for TRAIN_S seconds
#    of training (benchmarks/train_curve.py, GPU, batch 64, lr 0.002) into OUT_DIR/run (which
#    must not exist: a run folder with a checkpoint would be resumed instead). The recipe's time
#    budget plans the steps: its probe, then revisions from the rate measured during the run
#    (train/budget.py), since the loaders of a GPU run reach full speed only after a minute or
#    so, and a plan from the first seconds leaves much of the time unused;
# 3. writes OUT_DIR/best.ckpt and OUT_DIR/last.ckpt without optimiser state (13 MB each: what
#    `dream export` and `--set trainer.init_from=` need).
# Extra KEY=VALUE arguments override the recipe (train_curve.py --set). `dream` runs as
# `python -m dream.cli`, so a checkout on PYTHONPATH needs no installed console script.
#
# The bundled model's GPU stages ran it on an NVIDIA H100 with 16 CPU cores and MUJOCO_GL=egl;
# the model card (dream/models/panda_cpu.md) gives the commands and figures. Without a GPU, add
# trainer.accelerator=cpu (checked at toy size); for real CPU training use
# benchmarks/train_curve.py directly.
set -euo pipefail
if [ $# -lt 7 ]; then
  sed -n 2,4p "$0" >&2
  exit 2
fi
init=$1 out=$2 data=$3 seed=$4 num=$5 render_s=$6 train_s=$7
shift 7
repo=$(cd "$(dirname "$0")/.." && pwd)
init_from=$init
if [ "$init" = none ]; then init_from=null; fi
batch=64
workers=$(nproc)
loaders=$((workers > 2 ? workers - 1 : 1))
export MUJOCO_GL=${MUJOCO_GL:-egl} PYTHONUNBUFFERED=1
if [ -e "$out/run" ]; then
  echo "gpu_finetune.sh: $out/run exists; give a new OUT_DIR (a run folder would be resumed)" >&2
  exit 2
fi
mkdir -p "$out" "$data"

render() {  # SEED NUM SECONDS DIR [dream synth options...]: a render that fails stops here
  local seed=$1 n=$2 seconds=$3 dir=$4
  shift 4
  echo "== render: up to $n frames, seed $seed, $workers processes, at most $seconds s ($*)"
  set +e
  timeout "$seconds" python -m dream.cli synth --robot panda --num "$n" --workers "$workers" \
    --seed "$seed" "$@" --out "$dir" | tr '\r' '\n' | tail -n 2
  local rc=${PIPESTATUS[0]}
  set -e
  if [ "$rc" -ne 0 ] && [ "$rc" -ne 124 ]; then  # 124: stopped by the time limit
    echo "gpu_finetune.sh: dream synth failed (exit $rc); see its error above" >&2
    exit 1
  fi
}
if [ -n "${SYNTH_CONFIG:-}" ]; then
  render "$seed" $((num / 2)) $((render_s / 2)) "$data/train_$seed" \
    --set distractors.held_prob=0.5
  render $((seed + 1)) $((num / 2)) $((render_s / 2)) \
    "$data/train_$((seed + 1))_$(basename "$SYNTH_CONFIG" .yaml)" --config "$SYNTH_CONFIG"
else
  render "$seed" "$num" "$render_s" "$data/train_$seed" --set distractors.held_prob=0.5
fi
python -m dream.cli synth --robot panda --num 200 --workers "$workers" --seed 2000 \
  --out "$data/heldout" | tr '\r' '\n' | tail -n 1
train_dirs=$(ls -d "$data"/train_* | paste -sd, -)
first_train=${train_dirs%%,*}
frames=$(find "$data" -path "$data/train_*/[0-9]*.json" | wc -l)
echo "== training frames: $frames in [$train_dirs]"

minutes=$(python -c "print($train_s / 60)")
common=(--set "data.train=[$train_dirs]" --set trainer.accelerator=gpu --set trainer.devices=1
        --set data.batch_size=$batch --set data.num_workers=$loaders --set optim.lr=0.002
        --set "trainer.init_from=$init_from" --set trainer.checkpoint_every_n_steps=0
        --set trainer.time_budget_minutes="$minutes" --set trainer.max_steps=null)
for kv in "$@"; do common+=(--set "$kv"); done

echo "== train: $train_s s of training"
python "$repo/benchmarks/train_curve.py" "$first_train" "$data/heldout" --out "$out/run" \
  --minutes "$(python -c "print(1.2 * $minutes)")" --eval-every-s 60 "${common[@]}"

python - "$out" <<'EOF'
import sys
from pathlib import Path
import torch
from train.checkpoint import read_checkpoint
out = Path(sys.argv[1])
for name in ("best", "last"):
    ckpt = read_checkpoint(out / "run" / f"{name}.ckpt")   # checked to be a dream train one
    for key in ("optimizer_states", "lr_schedulers", "callbacks", "loops"):
        ckpt.pop(key, None)
    torch.save(ckpt, out / f"{name}.ckpt")
    print(f"{out / name}.ckpt: epoch {ckpt['epoch']}, step {ckpt['global_step']}")
EOF
