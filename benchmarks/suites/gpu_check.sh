#!/usr/bin/env bash
# Issue 27's GPU checks in parts, each sized for a device call of at most 10 minutes on an H100/H200.
#
# Usage (from the repository root, on the GPU host; PYTHONPATH=src when the package is not installed):
#
#   PYTHONPATH=src bash benchmarks/suites/gpu_check.sh OUT PART...
#
# Parts, in order, each under its own time limit (seconds); a part that runs over is cut and marked so:
#   data     (150) simulate analytic-orbs at SIZE×SIZE (gray, 1000 steps, 8 test views; JOBS workers) into WORK
#   kernels  (180) the Triton and gather lookups against grid_sample, and the Triton compositing and march
#            against torch's, on the GPU (tests/test_vm_triton.py, tests/test_vm_gather.py,
#            tests/test_volume_triton.py, tests/test_march_triton.py): run before `profile` times them
#   lookup   (120) bench_lookup: each lookup's forward, and forward + backward, against grid_sample's, 2²⁰
#            points, R 300; the Triton kernels at each of LAUNCHES (points x warps a program)
#   composite (60) bench_composite: the compositing's forward + backward, torch's and composite=triton's,
#            against the scatter reference, BATCH rays of about 64 samples
#   march    (60) bench_march: the march, packed and in the static budget, torch's and march=triton's,
#            against the packed torch march, BATCH rays, R 300
#   tests    (300) the CUDA tests (pytest -m cuda; the CUDA-graph step with static_visible among them)
#   optim    (120) bench_optimizer: one Adam update of the R GRID grid model, train's fused Adam against
#            --compile-optimizer's compiled update (compiling timed apart)
#   occupancy (60) bench_occupancy: an occupancy update on the lattice against the point lookups, R 300, G 128
#   train    (120) METHOD, BATCH rays, ITERS iterations, eager, PSNR every 250: the run `profile` starts from
#   profile  (160 per variant) profile_cuda_step from that run's last step, METHOD at BATCH and SMALL rays,
#            the compiled static step (static_samples=64 static_colors=16) with each of VARIANTS (default:
#            lookup=triton, as it is, static_visible=24, lookup=gather; a variant joins field options and
#            compile-optimizer with +, e.g. lookup=triton+compile-optimizer): ms a step, rays/s, GPU-busy
#            share, launches and host syncs
#   fast     (300) METHOD trained as `train` does with the fast GPU recipe: COMPILE, the static budget
#            (static_samples=64 static_colors=16) and lookup=LOOKUP (triton), compiling included in its
#            seconds; its test PSNR against `train`'s is what a default needs
#   ttq      (560) METHOD's time-to-quality curve (the oracle's by default): PSNR every 20 s for 480 s of training
#   compile  (330) bench_compile_cache: seconds spent compiling the static step (SMALL rays, 200 steps),
#            one graph a run against two, and with a warm cache
# Suggested calls, most needed first, each with part caps summing under a call's 600 s (a session has
# about 15 minutes of device time, starts included; a part cut by the call's end is lost, the ones before
# it are in OUT): METHOD=spike-integral with `data train fast`, then METHOD=spike-integral
# VARIANTS="lookup=triton+compile-optimizer lookup=triton+composite=triton+march=triton static_visible=24"
# with `profile`, then `kernels composite march tests`
# (docs/performance.md); `optim occupancy compile ttq` when time is left.
#
# OUT/summary.txt gathers each part's exit code and key lines (the figures to copy into
# docs/performance.md); OUT/PART.txt holds its whole output. WORK (default .gpu-work, ignored by git)
# keeps the dataset and the run between calls on a warm machine. Environment: METHOD (nerf-gt; spike-integral
# is the default spike method), DEVICE (cuda), SIZE (400),
# JOBS (8), BATCH (16384), SMALL (4096), ITERS (2000), COMPILE (--compile; empty for the eager step), LOOKUP
# (the `fast` part's lookup: triton), GRID (the `optim` part's grid resolution: 300), WARMUP/STEPS/PSTEPS
# (profile_cuda_step's --warmup/--steps/--profile-steps: 15/60/3), LAUNCHES (64x4,32x4,64x8,128x8),
# VARIANTS (the profile's field options,
# `base` for none), PYTHON (python). The CPU test runs `data train profile` at a tiny size
# (tests/test_gpu_check.py).
set -u -o pipefail
OUT=${1:?usage: gpu_check.sh OUT PART...}
shift
DEVICE=${DEVICE:-cuda} SIZE=${SIZE:-400} BATCH=${BATCH:-16384} SMALL=${SMALL:-4096} ITERS=${ITERS:-2000}
COMPILE=${COMPILE---compile} WARMUP=${WARMUP:-15} STEPS=${STEPS:-60} PSTEPS=${PSTEPS:-3}
PYTHON=${PYTHON:-python} WORK=${WORK:-.gpu-work} JOBS=${JOBS:-8} LOOKUP=${LOOKUP:-triton} LAUNCHES=${LAUNCHES:-64x4,32x4,64x8,128x8}
VARIANTS=${VARIANTS:-lookup=triton base static_visible=24 lookup=gather}
METHOD=${METHOD:-nerf-gt} GRID=${GRID:-300}
DATA=$WORK/orbs$SIZE RUN=$WORK/$METHOD$SIZE
STATIC=(--field-option static_samples=64 --field-option static_colors=16)
mkdir -p "$OUT" "$WORK"
SUMMARY=$OUT/summary.txt

note() { echo "$*" | tee -a "$SUMMARY"; }

# part NAME LIMIT GREP COMMAND...: run COMMAND into OUT/NAME.txt under LIMIT s; note its code and the
# output lines matching GREP (an extended regex)
part() {
  local name=$1 limit=$2 pattern=$3
  shift 3
  local start=$SECONDS
  timeout "$limit" "$@" >"$OUT/$name.txt" 2>&1
  local code=$?
  local how="rc $code"
  [ "$code" -eq 124 ] && how="cut at $limit s"
  note "== $name: $how, $((SECONDS - start)) s"
  grep -E "$pattern" "$OUT/$name.txt" | tail -n 40 | tee -a "$SUMMARY"
  return 0
}

note "gpu_check $(date -u +%FT%TZ) method=$METHOD device=$DEVICE size=$SIZE batch=$BATCH iters=$ITERS compile='$COMPILE'"
note "$($PYTHON -c 'import torch; print("torch", torch.__version__, "cuda", torch.cuda.is_available(),
  torch.cuda.get_device_name() if torch.cuda.is_available() else "")' 2>&1)"
for name in "$@"; do
  case $name in
    data)
      [ -f "$DATA/transforms.json" ] && { note "== data: $DATA is there"; continue; }
      part data 150 "^wrote" "$PYTHON" -m spikenerf simulate --scene analytic-orbs --width "$SIZE" \
        --height "$SIZE" --color gray --jobs "$JOBS" --out "$DATA" ;;
    kernels)
      part kernels 180 "passed|failed|error" "$PYTHON" -m pytest -p no:cacheprovider \
        tests/test_vm_triton.py tests/test_vm_gather.py tests/test_volume_triton.py tests/test_march_triton.py ;;
    lookup)
      part lookup 120 "^device|^C =|^\| [a-z]" "$PYTHON" -m benchmarks.tools.bench_lookup --device "$DEVICE" \
        --triton-launch "$LAUNCHES" ;;
    composite)
      part composite 60 "^device|^\| [a-z]|^triton" "$PYTHON" -m benchmarks.tools.bench_composite \
        --device "$DEVICE" --rays "$BATCH" --samples 64 ;;
    march)
      part march 60 "^device|^\| [a-z]|^triton" "$PYTHON" -m benchmarks.tools.bench_march \
        --device "$DEVICE" --rays "$BATCH" --resolution 300 ;;
    tests)
      part tests 300 "passed|failed|error" "$PYTHON" -m pytest -m cuda -p no:cacheprovider \
        tests/test_cuda.py tests/test_compile.py tests/test_compiled_step.py tests/test_inference.py \
        tests/test_integral.py tests/test_learned_targets.py tests/test_train_device.py tests/test_vm_lattice.py ;;
    optim)
      part optim 120 "^grid|compil|ms an update|speed" "$PYTHON" -m benchmarks.tools.bench_optimizer \
        --device "$DEVICE" --resolution "$GRID" ;;
    occupancy)
      part occupancy 60 "^R |ms|points /" "$PYTHON" -m benchmarks.tools.bench_occupancy --device "$DEVICE" \
        --resolution 300 --cells 128 ;;
    train)
      rm -rf "$RUN"
      part train 120 "^trained" "$PYTHON" -m spikenerf train "$DATA" --method "$METHOD" --batch "$BATCH" \
        --iters "$ITERS" --eval-every 250 --eval-views 8 --quiet --device "$DEVICE" --out "$RUN"
      [ -f "$RUN/curves.csv" ] && note "$(cat "$RUN/curves.csv")" ;;
    fast)
      rm -rf "$RUN-fast"
      part fast 300 "^trained" "$PYTHON" -m spikenerf train "$DATA" --method "$METHOD" --batch "$BATCH" \
        --iters "$ITERS" --eval-every 250 --eval-views 8 --quiet --device "$DEVICE" --out "$RUN-fast" \
        $COMPILE "${STATIC[@]}" --field-option "lookup=$LOOKUP"
      [ -f "$RUN-fast/curves.csv" ] && note "$(cat "$RUN-fast/curves.csv")" ;;
    profile)
      for variant in $VARIANTS; do
        extra=()  # VARIANT: base, or KEY=VALUE field options and compile-optimizer joined by +
        for piece in ${variant//+/ }; do
          case $piece in
            base) ;;
            compile-optimizer) extra+=(--compile-optimizer) ;;
            *) extra+=(--field-option "$piece") ;;
          esac
        done
        part "profile-${variant//=/-}" 160 "ms/step" "$PYTHON" -m benchmarks.tools.profile_cuda_step "$DATA" \
          --device "$DEVICE" --methods "$METHOD" --start "$METHOD=$RUN" --batches "$BATCH,$SMALL" \
          --warmup "$WARMUP" --steps "$STEPS" --profile-steps "$PSTEPS" $COMPILE "${STATIC[@]}" ${extra[@]+"${extra[@]}"}
      done ;;
    ttq)
      part ttq 560 "^\|" "$PYTHON" -m benchmarks.experiments.bench_time_to_quality \
        --dataset "$DATA" --device "$DEVICE" --jobs 1 --runs "$METHOD:40000" --batch "$BATCH" --budget 480 \
        --wall-limit 540 --eval-seconds 20 --thresholds 28,30 --csv "$OUT/ttq.csv" ;;
    compile)
      part compile 330 "compil|step" "$PYTHON" -m benchmarks.tools.bench_compile_cache --dataset "$DATA" \
        --device "$DEVICE" --batch "$SMALL" --static-samples 64 ;;
    *)
      note "== $name: unknown part (data kernels lookup composite march tests optim occupancy train fast profile ttq compile)"
      exit 2 ;;
  esac
done
