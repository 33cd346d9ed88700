#!/usr/bin/env bash
# Three BMM trainings on LaFAN1 subjects 1–4 side by side on one GPU, each for the same
# wall time, then each evaluated on subject 5 (curves before IK, 10 DDIM steps):
#
#   paper_x0        the paper's model (17.4 M) and training: x0 prediction, Min-SNR-γ 5,
#                   batch 64, lr 1e-4 (BMM Table 4)
#   paper_residual  the paper's model with our recipe: residual prediction over the
#                   reference curves, no Min-SNR weighting, handles off the grid half of
#                   the time, batch 256, lr 2e-4
#   cpu_residual    the CPU-size model (2.3 M) with the same recipe: width/depth at equal
#                   wall time
#
#   OUT=results/gpu bash experiments/gpu_lafan1.sh LAFAN1_ZIP [TRAIN_SECONDS] [KILL_AFTER_S]
#
# It sets JAX_DEFAULT_MATMUL_PRECISION=highest (unless set): the runs of 2026-11-26 were measured so.
#
# KILL_AFTER_S counts from the script's start. Runs unchanged on a CPU (slowly). Writes under $OUT: results.tar.gz (every job's JSON,
# Markdown report, learning-curve PNG and JSON, log) and the trained models as float16
# tars (the paper-size one split into 15 MB parts, to fit a transfer limit). LaFAN1 is
# CC BY-NC-ND: these weights stay out of the repository.
set -u
DATA=${1:?usage: gpu_lafan1.sh LAFAN1_ZIP [TRAIN_SECONDS] [KILL_AFTER_S]}
TRAIN_S=${2:-330}
KILL_S=${3:-520}
OUT=${OUT:-results/gpu}
RUNS=${RUNS:-/tmp/bezmotion-gpu-runs}
mkdir -p "$OUT" "$RUNS/logs"
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1
export BEZMOTION_CACHE=${BEZMOTION_CACHE:-/tmp/bezmotion-cache}
export XLA_PYTHON_CLIENT_MEM_FRACTION=0.25  # three processes share the GPU
export JAX_DEFAULT_MATMUL_PRECISION=${JAX_DEFAULT_MATMUL_PRECISION:-highest}  # as measured; the curve fit asks for it itself
python3 -c "import jax, flax, optax, optimistix, orbax.checkpoint; print('jax', jax.__version__, 'flax', flax.__version__, 'optax', optax.__version__, jax.devices())"
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader 2>/dev/null

# Fit the curve datasets once (cached) so the three jobs do not fit them three times.
python3 -c "
from bezmotion.data.sources import load_corpus
from bezmotion.data.curves import curve_dataset
c = load_corpus('lafan1', source='$DATA', progress=False)
print('train windows', len(curve_dataset(c, 'train', progress=False)), 'validation windows', len(curve_dataset(c, 'validation', progress=False)))
"

# GPU latency and throughput of sampling (random weights; nothing else runs on the GPU yet).
timeout 90 python3 benchmarks/bmm_inference.py --repeats 50 --out "$RUNS/bmm_inference.json" >"$RUNS/logs/bmm_inference.log" 2>&1
tail -3 "$RUNS/logs/bmm_inference.log"; echo "benchmark done at $SECONDS s"

common=(--corpus lafan1 --data "$DATA" --steps 1000000 --train-seconds "$TRAIN_S" --eval-every "${EVAL_EVERY:-4000}" --curve-windows 200
        --checkpoint-every 5000 --eval-windows "${EVAL_WINDOWS:-1000}" --table6-steps 10 --no-progress)
ours=(--prediction residual --min-snr-gamma 0 --off-grid-handles 0.5 --batch-size 256 --learning-rate 2e-4)
declare -A args=(
  [paper_x0]="--config paper"
  [paper_residual]="--config paper ${ours[*]}"
  [cpu_residual]="--config cpu ${ours[*]}"
)
for job in paper_x0 paper_residual cpu_residual; do
  # shellcheck disable=SC2086
  timeout -s TERM "$((KILL_S - SECONDS))" python3 experiments/bmm_lafan1.py "${common[@]}" ${args[$job]} \
    --run-dir "$RUNS/$job" --out "$RUNS/$job.json" >"$RUNS/logs/$job.log" 2>&1 &
done
wait
echo "jobs done at $SECONDS s"
for job in paper_x0 paper_residual cpu_residual; do echo "== $job"; tail -5 "$RUNS/logs/$job.log"; done

# Bring back: reports and curves, then the models in float16.
(cd "$RUNS" && tar czf "$OUT/results.tar.gz" logs ./*.json ./*.md ./*.png ./*/learning_curve.json 2>/dev/null)
for job in paper_residual cpu_residual paper_x0; do
  [ -d "$RUNS/$job/model" ] || continue
  python3 -c "
from bezmotion.bmm.sampling import load_model, save_model
save_model('$RUNS/${job}_fp16', load_model('$RUNS/$job/model'), storage_dtype='float16')" || continue
  tar cf "$RUNS/$job.tar" -C "$RUNS" "${job}_fp16"
done
# Transfer limit: 64 MiB in all, 16 MiB a file: the CPU-size model whole, one paper-size model in parts.
[ -f "$RUNS/cpu_residual.tar" ] && cp "$RUNS/cpu_residual.tar" "$OUT/"
for job in paper_residual paper_x0; do
  if [ -f "$RUNS/$job.tar" ]; then split -b 15M "$RUNS/$job.tar" "$OUT/$job.tar.part-"; break; fi
done
ls -la "$OUT"
