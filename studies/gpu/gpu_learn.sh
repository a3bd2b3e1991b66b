#!/usr/bin/env bash
# The lent GPU machine's run for what the GPU issue still asks (AssemblingKits from pixels, Diffusion LiftPegUpright
# from pixels, each <= 10 minutes of training), as studies/gpu/gpu_run.py steps; install and carry: studies/gpu/README.md.
#   on the machine, second command:  (setsid nohup bash studies/gpu/gpu_learn.sh run /tmp/kb >/dev/null 2>&1 &);
#                                    bash studies/gpu/gpu_learn.sh collect 540 /tmp/kb
#   a later command polls:           bash studies/gpu/gpu_learn.sh collect 300 /tmp/kb
# (setsid: the run outlives the command that started it)
#   its test on the CPU:             TINY=1 bash studies/gpu/gpu_learn.sh run /tmp/kbtiny
# Recordings made on the CPU beforehand save the machine's minutes: `python studies/gpu/gpu_pack.py ak=DIR diffusion=DIR`
# splits them into .gpu/data1, .gpu/data2, ...; send each in its own command, which must copy it off at once (a
# carried folder is gone at the next command unless carried again):   bash studies/gpu/gpu_learn.sh receive /tmp/kb
# `run` trains on DIR/data/ak and DIR/data/diffusion instead of recording, once `gpu_pack.py --check` finds them whole
# (a name not packed is recorded on the machine as before). wheels.sh does not fetch diffusers, which Diffusion
# needs: `pip download --no-deps diffusers==0.39.0 importlib-metadata==10.2.0 -d .gpu/whl3` (uv.lock's versions),
# carried beside a data folder and installed there with `source .gpu/device.sh whl3`.
# The two trainings share the GPU at once: alone each kept it under a third busy (docs/studies/gpu.md, "Image configs
# on one GPU"). Figures land in DIR/{ak,diffusion}/learn.json as each step ends; `collect` packs them into $OUT.
set -uo pipefail
cd "$(dirname "$0")/../.."
what=${1:?run DIR | collect SECONDS DIR | receive DIR}
if [ "$what" = receive ]; then  # the packed folders carried in this command, copied into DIR/data
  dir=${2:-/tmp/kb}; mkdir -p "$dir/data"; found=0
  for part in "${PACKED:-.gpu}"/data*/; do [ -d "$part" ] && cp -r "$part". "$dir/data/" && found=1; done
  [ $found = 1 ] || { echo "gpu_learn.sh: no packed folder (.gpu/data*) came with this command" >&2; exit 2; }
  du -sm "$dir/data"; exit 0
fi
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
[ "$what" = run ] || { echo "gpu_learn.sh: unknown command '$what' (choose run, collect or receive)" >&2; exit 2; }
dir=${2:-/tmp/kb}; mkdir -p "$dir"
# a fresh log: `collect` waits for this run's "all done", not an earlier one's (learn.json keeps what that finished)
[ -f "$dir/run.log" ] && mv "$dir/run.log" "$dir/run.log.prev"
exec > >(tee "$dir/run.log") 2>&1
PY=${PY:-python3}
# AssemblingKits: the CPU config (both cameras at 64x64, the base camera framing the board) moved to the GPU with a
# 8x larger batch, the CPU runs' 640 k samples (a batch of 256 takes about as long an update as one of 64: the update
# is bound by launching kernels). On one H200 (2026-11-29), with the Diffusion GPU config beside it: 0.059 and 0.054 s
# a step, 4.2 and 4.5 minutes of training, each scored in 1-2 minutes (docs/studies/gpu.md). Diffusion: the CPU config
# as shipped, on its recording whose swing ends in the air (96.5% over three training seeds on 2 CPU cores; 68% at
# one seed from the recording the GPU config trains on), in float32 (its bf16 autocast is the CPU's lever).
AK=${AK_CONFIG:-act_assembling_kits_rgb_cpu}; AK_DEMOS=${AK_DEMOS:-1000}; AK_STEPS=${AK_STEPS:-2500}
AK_EXTRA=${AK_EXTRA:---policy.device=cuda --batch_size=256 --num_workers=8}
DF=${DF_CONFIG:-diffusion_lift_peg_upright_rgb_cpu}; DF_DEMOS=${DF_DEMOS:-200}; DF_STEPS=${DF_STEPS:-5000}
DF_EXTRA=${DF_EXTRA:---policy.device=cuda --policy.use_amp=false --num_workers=6}
# the recordings split the 14 free cores; each training then has its own loader workers
AK_W=9; DF_W=5; TINY_ARG=""
if [ -n "${TINY:-}" ]; then AK_W=1; DF_W=1; TINY_ARG=--tiny; AK_EXTRA=""; DF_EXTRA=""; fi
learn() {  # learn NAME CONFIG DEMOS STEPS WORKERS EXTRA
  local variant=() data=(); [ -n "$6" ] && variant=(--extra="$6" --tag gpu)
  [ -f "$dir/data/$1/meta/kitbench_recording.json" ] && data=(--data "$dir/data/$1")
  $PY studies/gpu/gpu_run.py --plan learn --out "$dir/$1" --config "$2" --demos "$3" --steps "$4" --workers "$5" \
    --eval-episodes 100 --eval-batch 25 "${variant[@]}" "${data[@]}" $TINY_ARG > "$dir/$1.log" 2>&1
  echo "== $1 ended rc=$? $(date +%T)"; tail -1 "$dir/$1.log"
}
echo "== start $(date +%T)"
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader 2>/dev/null
if [ -f "$dir/data/gpu_pack.json" ]; then $PY studies/gpu/gpu_pack.py --check "$dir/data" || exit 1; fi
learn ak "$AK" "$AK_DEMOS" "$AK_STEPS" "$AK_W" "$AK_EXTRA" & ak=$!
learn diffusion "$DF" "$DF_DEMOS" "$DF_STEPS" "$DF_W" "$DF_EXTRA" & df=$!
wait $ak $df  # not a bare wait: that would wait for the log's tee too
echo "== all done $(date +%T)"
