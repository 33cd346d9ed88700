#!/usr/bin/env bash
# LaFAN1 trainings on subjects 1–4 side by side on one GPU, each for the same wall time,
# then each evaluated on subject 5 (BMMs: curves before IK, 10 DDIM steps; IK: Table 2
# effector sets). JOBS picks them (default: paper_x0 paper_residual cpu_residual):
#
#   paper_x0        the paper's model (17.4 M) and training: x0 prediction, Min-SNR-γ 5,
#                   batch 64, lr 1e-4 (BMM Table 4)
#   paper_residual  the paper's model with our recipe: residual prediction over the
#                   reference curves, no Min-SNR weighting, handles off the grid half of
#                   the time, batch 256, lr 2e-4
#   cpu_residual    the CPU-size model (2.3 M) with the same recipe: width/depth at equal
#                   wall time
#   paper_cosine    paper_residual with warm-up + cosine decay to 0.1× at PAPER_STEPS
#   cpu_cosine      cpu_residual with warm-up + cosine decay to 0.1× at CPU_STEPS
#   ik_paper        the paper-size learned IK (ProtoRes scale, ≈ 22 M), cosine to IK_STEPS
#
#   OUT=results/gpu bash experiments/gpu_lafan1.sh LAFAN1_ZIP [TRAIN_SECONDS] [KILL_AFTER_S]
#   JOBS="paper_cosine cpu_cosine ik_paper" PAPER_STEPS=5000 OUT=… bash experiments/gpu_lafan1.sh …
#
# Precision: the curve fit asks for full float32 products itself (bezmotion._src.linalg), so
# the networks may use the GPU's fast default (TF32). The script fits the datasets first
# with the default and says whether that converged; if it did not, it sets
# JAX_DEFAULT_MATMUL_PRECISION=highest for everything.
#
# KILL_AFTER_S counts from the script's start. Runs unchanged on a CPU (slowly). Writes under $OUT: results.tar.gz (every job's JSON,
# Markdown report, learning-curve PNG and JSON, log) and the trained models as float16
# tars (CPU-size whole, paper-size ones split into 15 MB parts, to fit the transfer
# limit of 8 files). LaFAN1 is CC BY-NC-ND: these weights stay out of the repository.
set -u
DATA=${1:?usage: gpu_lafan1.sh LAFAN1_ZIP [TRAIN_SECONDS] [KILL_AFTER_S]}
TRAIN_S=${2:-330}
KILL_S=${3:-520}
OUT=${OUT:-results/gpu}
RUNS=${RUNS:-/tmp/bezmotion-gpu-runs}
mkdir -p "$OUT" "$RUNS/logs"
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1
export BEZMOTION_CACHE=${BEZMOTION_CACHE:-/tmp/bezmotion-cache}
JOBS=${JOBS:-paper_x0 paper_residual cpu_residual}
read -ra jobs <<<"$JOBS"
export XLA_PYTHON_CLIENT_MEM_FRACTION=${XLA_PYTHON_CLIENT_MEM_FRACTION:-$(python3 -c "print(round(0.9 / ${#jobs[@]}, 2))")}  # the jobs share the GPU
python3 -c "import jax, flax, optax, optimistix, orbax.checkpoint; print('jax', jax.__version__, 'flax', flax.__version__, 'optax', optax.__version__, jax.devices())"
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader 2>/dev/null

# Fit the curve datasets once (cached) so the jobs do not fit them each; with the default
# precision unless the caller set one, and with full float32 everywhere if that fails.
fit_datasets() {
  python3 -c "
from bezmotion.data.sources import load_corpus
from bezmotion.data.curves import curve_dataset
c = load_corpus('lafan1', source='$DATA', progress=False)
print('train windows', len(curve_dataset(c, 'train', progress=False)), 'validation windows', len(curve_dataset(c, 'validation', progress=False)))
" 2>&1 | tail -3
  return "${PIPESTATUS[0]}"
}
if fit_datasets; then
  echo "curve fit converged with matmul precision: ${JAX_DEFAULT_MATMUL_PRECISION:-default}"
else
  echo "curve fit failed with matmul precision ${JAX_DEFAULT_MATMUL_PRECISION:-default}: retrying with highest"
  export JAX_DEFAULT_MATMUL_PRECISION=highest
  fit_datasets || exit 1
fi
echo "datasets ready at $SECONDS s"

if [ -n "${BENCHMARK:-}" ]; then  # GPU latency and throughput of sampling (random weights; nothing else runs yet)
  timeout 90 python3 benchmarks/bmm_inference.py --repeats 50 --out "$RUNS/bmm_inference.json" >"$RUNS/logs/bmm_inference.log" 2>&1
  tail -3 "$RUNS/logs/bmm_inference.log"; echo "benchmark done at $SECONDS s"
fi

common=(--corpus lafan1 --data "$DATA" --steps 1000000 --train-seconds "$TRAIN_S" --eval-every "${EVAL_EVERY:-4000}" --curve-windows 200
        --checkpoint-every 5000 --eval-windows "${EVAL_WINDOWS:-1000}" --table6-steps 10 --no-progress)
ours=(--prediction residual --min-snr-gamma 0 --off-grid-handles 0.5 --batch-size 256 --learning-rate 2e-4)
cosine=(--lr-schedule cosine --warmup-steps "${WARMUP_STEPS:-500}")
declare -A args=(
  [paper_x0]="--config paper"
  [paper_residual]="--config paper ${ours[*]}"
  [cpu_residual]="--config cpu ${ours[*]}"
  [paper_cosine]="--config paper ${ours[*]} ${cosine[*]} --steps ${PAPER_STEPS:-5000}"
  [cpu_cosine]="--config cpu ${ours[*]} ${cosine[*]} --steps ${CPU_STEPS:-12000}"
)
for job in "${jobs[@]}"; do
  if [ "$job" = ik_paper ]; then
    timeout -s TERM "$((KILL_S - SECONDS))" python3 experiments/train_ik.py --corpus lafan1 --data "$DATA" --config paper \
      --steps "${IK_STEPS:-20000}" --train-seconds "$TRAIN_S" --checkpoint-every 2500 --no-progress \
      --out-dir "$RUNS/$job" >"$RUNS/logs/$job.log" 2>&1 &
  elif [ -n "${args[$job]:-}" ]; then
    # shellcheck disable=SC2086  (later flags override common ones: --steps)
    timeout -s TERM "$((KILL_S - SECONDS))" python3 experiments/bmm_lafan1.py "${common[@]}" ${args[$job]} \
      --run-dir "$RUNS/$job" --out "$RUNS/$job.json" >"$RUNS/logs/$job.log" 2>&1 &
  else
    echo "unknown job $job (known: ${!args[*]} ik_paper)"; exit 2
  fi
done
wait
echo "jobs done at $SECONDS s"
for job in "${jobs[@]}"; do echo "== $job"; tail -12 "$RUNS/logs/$job.log"; done

# Bring back: reports and curves, then the models in float16.
(cd "$RUNS" && tar czf "$OUT/results.tar.gz" logs ./*.json ./*.md ./*.png ./*/learning_curve.json ./*/training.json 2>/dev/null)
for job in "${jobs[@]}"; do
  [ -d "$RUNS/$job/model" ] || continue
  if [ "$job" = ik_paper ]; then
    save="from bezmotion.ik.protores import load_ik_model as load, save_ik_model as save"
  else
    save="from bezmotion.bmm.sampling import load_model as load, save_model as save"
  fi
  python3 -c "$save; save('$RUNS/${job}_fp16', load('$RUNS/$job/model'), storage_dtype='float16')" || continue
  tar cf "$RUNS/$job.tar" -C "$RUNS" "${job}_fp16"
  # Transfer limit: 16 MiB a file, 8 files: larger models come back in 15 MB parts.
  if [ "$(stat -c %s "$RUNS/$job.tar")" -lt 15000000 ]; then cp "$RUNS/$job.tar" "$OUT/"; else split -b 15M "$RUNS/$job.tar" "$OUT/$job.tar.part-"; fi
done
ls -la "$OUT"
