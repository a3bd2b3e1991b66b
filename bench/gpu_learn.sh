#!/usr/bin/env bash
# The lent GPU machine's run for what the GPU issue still asks (AssemblingKits from pixels, Diffusion LiftPegUpright
# from pixels, each <= 10 minutes of training), as bench/gpu_run.py steps; install and carry: ../shared/gpu/README.md.
#   on the machine, second command:  (setsid nohup bash bench/gpu_learn.sh run /tmp/kb >/dev/null 2>&1 &);
#                                    bash bench/gpu_learn.sh collect 540 /tmp/kb
#   a later command polls:           bash bench/gpu_learn.sh collect 300 /tmp/kb
# (setsid: the run outlives the command that started it)
#   its test on the CPU:             TINY=1 bash bench/gpu_learn.sh run /tmp/kbtiny
# The two trainings share the GPU at once: alone each kept it under a third busy (docs/learnability.md, "Image configs
# on one GPU"). Figures land in DIR/{ak,diffusion}/learn.json as each step ends; `collect` packs them into $OUT.
set -uo pipefail
cd "$(dirname "$0")/.."
what=${1:?run DIR | collect SECONDS DIR}
if [ "$what" = collect ]; then
  dir=${3:-/tmp/kb}; end=$((SECONDS + ${2:-0}))
  while [ $SECONDS -lt $end ] && ! grep -q "== all done" "$dir/run.log" 2>/dev/null; do sleep 5; done
  # figures and logs only: datasets and checkpoints are too large to bring back
  (cd "$(dirname "$dir")" && find "$(basename "$dir")" \( -path "*/data" -o -path "*/train" \) -prune -o -type f \
    -size -4M -print | tar czf "${OUT:-/tmp}/kb.tgz" -T -)
  tail -30 "$dir/run.log"
  for log in "$dir"/*/logs/train_*.log; do [ -f "$log" ] && echo "$log: $(grep -ao 'step:[^ ]* .*' "$log" | tail -1)"; done
  nvidia-smi --query-gpu=utilization.gpu,memory.used --format=csv,noheader 2>/dev/null
  exit 0
fi
[ "$what" = run ] || { echo "gpu_learn.sh: unknown command '$what' (choose run or collect)" >&2; exit 2; }
dir=${2:-/tmp/kb}; mkdir -p "$dir"; exec > >(tee -a "$dir/run.log") 2>&1
PY=${PY:-python3}
# AssemblingKits: the CPU config (both cameras at 64x64, the base camera framing the board) moved to the GPU with a
# larger batch; Diffusion: the GPU config as shipped. Steps are estimates: the 128x128 AssemblingKits config ran 18.5
# steps/s at batch 64 on the last H200; Diffusion's rate on kitbench's reader is unmeasured. `collect` prints each
# training's last logged step: adjust AK_STEPS and DF_STEPS from it.
AK=${AK_CONFIG:-act_assembling_kits_rgb_cpu}; AK_DEMOS=${AK_DEMOS:-1000}; AK_STEPS=${AK_STEPS:-8000}
AK_EXTRA=${AK_EXTRA:---policy.device=cuda --batch_size=64 --num_workers=6}
DF=${DF_CONFIG:-diffusion_lift_peg_upright_rgb}; DF_DEMOS=${DF_DEMOS:-200}; DF_STEPS=${DF_STEPS:-4000}
DF_EXTRA=${DF_EXTRA:---num_workers=6}
# the recordings split the 14 free cores; each training then has its own loader workers
AK_W=9; DF_W=5; TINY_ARG=""
if [ -n "${TINY:-}" ]; then AK_W=1; DF_W=1; TINY_ARG=--tiny; AK_EXTRA=""; DF_EXTRA=""; fi
learn() {  # learn NAME CONFIG DEMOS STEPS WORKERS EXTRA
  local variant=(); [ -n "$6" ] && variant=(--extra="$6" --tag gpu)
  $PY bench/gpu_run.py --plan learn --out "$dir/$1" --config "$2" --demos "$3" --steps "$4" --workers "$5" \
    --eval-episodes 100 --eval-batch 25 "${variant[@]}" $TINY_ARG > "$dir/$1.log" 2>&1
  echo "== $1 ended rc=$? $(date +%T)"; tail -1 "$dir/$1.log"
}
echo "== start $(date +%T)"
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader 2>/dev/null
learn ak "$AK" "$AK_DEMOS" "$AK_STEPS" "$AK_W" "$AK_EXTRA" & ak=$!
learn diffusion "$DF" "$DF_DEMOS" "$DF_STEPS" "$DF_W" "$DF_EXTRA" & df=$!
wait $ak $df  # not a bare wait: that would wait for the log's tee too
echo "== all done $(date +%T)"
