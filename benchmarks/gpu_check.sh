#!/usr/bin/env bash
# The GPU checks of issue 30 as one prepared run on a lent device machine (one H200 or H100, Python 3.12
# with numpy, scipy, PyYAML, matplotlib and Pillow, no network). Fresh `mitsuforest render` processes of
# the open scene on `cuda_ad_mono`: this checkout against an earlier commit's, interleaved; the writer's
# threads once; the scan without its read-ahead once; a thin beam (1 fixed sub-ray) each; the CPU/GPU
# agreement table when a CPU render's manifest is given; one leg stage by stage and one writer worker's part
# step by step (benchmarks/profile_leg.py, writer.py --parts); then the scan and writer tests on the GPU.
#
#   bash benchmarks/gpu_check.sh prepare BASE [CPU_MANIFEST]   # here: cp312 wheels into .whl (slimmed
#                                                             # to ~50 MB), BASE's tree into .gpu/base
#   run(command="bash benchmarks/gpu_check.sh run", carry=[".whl", ".gpu"], timeout_s=500)   # there
#
# VARIANT and SCENE (defaults cuda_ad_mono, scenes/open.yaml) change what runs: `VARIANT=llvm_ad_mono
# SCENE=scenes/demo.yaml PATH=$PWD/.venv/bin:$PATH bash benchmarks/gpu_check.sh run` tries the script on a CPU
# (an absolute PATH: the base renders run from .gpu/base).
# Each render line gives the wall time, the manifest's stage times and the LAZ's SHA-256: the same
# bytes head and base unless the scan changed. About 7 minutes on an H200 with the models cached by
# the first render.
set -uo pipefail
VARIANT=${VARIANT:-cuda_ad_mono}
SCENE=${SCENE:-scenes/open.yaml}
ROOT=$(cd "$(dirname "$0")/.." && pwd)
cd "$ROOT"

prepare() {
  local base=${1:?usage: gpu_check.sh prepare BASE_COMMIT [CPU_MANIFEST]}
  grep -qx '/.whl/' .git/info/exclude || echo '/.whl/' >> .git/info/exclude
  grep -qx '/.gpu/' .git/info/exclude || echo '/.gpu/' >> .git/info/exclude
  rm -rf .gpu/base && mkdir -p .gpu/base
  if ! ls .whl/mitsuba-*.whl >/dev/null 2>&1; then      # wheels kept from an earlier prepare are reused
    rm -rf .whl.new && mkdir -p .whl.new
    # pip matches a platform tag exactly: lazrs and pymeshfix are manylinux2014 (2_17), Mitsuba 2_28.
    python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
      --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 -d .whl.new mitsuba==3.9.1 drjit==1.5.0 trimesh==5.2.0 manifold3d==3.5.4 \
      pymeshfix==0.18.1 laspy==2.7.0 lazrs==0.8.2 pyproj==3.7.2 || { echo "no wheels: pip download failed" >&2; exit 1; }
    # Only cuda_ad_mono and scalar_rgb of Mitsuba's variants, and the plugins a scan loads, travel.
    local wheel=(.whl.new/mitsuba-*.whl) plugin
    zip -q -d "${wheel[0]}" 'mitsuba/llvm_ad_*' 'mitsuba/cuda_ad_rgb*' 'mitsuba/cuda_ad_spectral*' \
      'mitsuba/cuda_ad_mono_polarized*' 'mitsuba/scalar_spectral*' 'mitsuba/data/srgb.coeff' 2>/dev/null
    for plugin in ellipsoids ellipsoidsmesh volpath volpathmis bsplinecurve linearcurve sdfgrid sunsky \
                  timed_sunsky ptracer hair measured measuredpolarized principledthin roughdielectric aov \
                  envmap bitmap polarizer retarder blendbsdf; do
      zip -q -d "${wheel[0]}" "mitsuba/plugins/$plugin.so" 2>/dev/null
    done
    rm -rf .whl && mv .whl.new .whl
  fi
  git archive "$base" mitsuforest scenes sensors pyproject.toml | tar -x -C .gpu/base
  echo "$base" > .gpu/base/COMMIT
  if [ -n "${2:-}" ]; then cp "$2" .gpu/cpu_manifest.json; fi
  du -sh .whl .gpu
}

render() {  # label checkout scene [VARIABLE=value ...]
  local label=$1 dir=$2 scene=$3; shift 3
  ( cd "$dir" && env PYTHONPATH="/tmp/site:$dir" "$@" /usr/bin/time -f "$label: %e s wall, %U s user, %M KB" \
      python3 -m mitsuforest render "$scene" --variant "$VARIANT" --quiet -o "$OUT/$label" --overwrite ) 2>&1 \
    | grep -v Warn | tail -3
  python3 - "$OUT/$label" <<'PY'
import glob, hashlib, json, sys
manifest = json.load(open(glob.glob(sys.argv[1] + "/*_manifest.json")[0]))
laz = glob.glob(sys.argv[1] + "/*.laz")[0]
stages = {k: round(v, 2) for k, v in manifest["timings_s"].items()}
print("   ", f"{manifest['points']:,} points", stages, "laz", hashlib.sha256(open(laz, "rb").read()).hexdigest()[:16])
PY
  find "$OUT/$label" -type f ! -name '*_manifest.json' -delete    # 2-3 GB a render in /dev/shm (RAM)
}

run() {
  local start=$SECONDS
  [ -d /tmp/site ] || python3 -m pip install -q --no-deps --no-index --target /tmp/site .whl/*.whl 2>&1 | tail -2
  export MITSUFOREST_CACHE=${MITSUFOREST_CACHE:-/dev/shm/cache} OUT=/dev/shm/o
  mkdir -p "$OUT"
  nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader 2>/dev/null
  echo "$(nproc) cores; base $(cat .gpu/base/COMMIT 2>/dev/null)"
  local base=$ROOT/.gpu/base
  python3 - "$SCENE" > scenes/_thin.yaml <<'PY'
import sys, yaml
scene = yaml.safe_load(open(sys.argv[1]))
scene.setdefault("simulation", {}).update(beam_samples=1, beam_pattern="fixed")
print(yaml.safe_dump(scene))
PY
  cp scenes/_thin.yaml "$base/scenes/_thin.yaml"
  render head_cold "$ROOT" "$SCENE"           # builds the tree models into the cache
  for i in 1 2; do
    render "head_$i" "$ROOT" "$SCENE"
    render "base_$i" "$base" "$SCENE"
  done
  render head_threads "$ROOT" "$SCENE" MITSUFOREST_WRITER_PROCESSES=0
  render head_no_read_ahead "$ROOT" "$SCENE" MITSUFOREST_READ_AHEAD=0   # the device and host in turn
  render head_thin "$ROOT" scenes/_thin.yaml
  render base_thin "$base" scenes/_thin.yaml
  if [ -f .gpu/cpu_manifest.json ]; then
    PYTHONPATH="/tmp/site:$ROOT" python3 benchmarks/agreement.py .gpu/cpu_manifest.json "$OUT"/head_1/*_manifest.json
  fi
  rm -f scenes/_thin.yaml
  echo "renders done at $((SECONDS - start)) s"
  # Where the scan's time goes on this host: one leg stage by stage, and one writer worker's part step by step.
  PYTHONPATH="/tmp/site:$ROOT" timeout 120 python3 benchmarks/profile_leg.py --scene "$SCENE" --variant "$VARIANT" \
    2>&1 | grep -v Warn | tail -11
  PYTHONPATH="/tmp/site:$ROOT" python3 benchmarks/writer.py --parts --dir /dev/shm 2>&1 | grep -v Warn
  PYTHONPATH="/tmp/site:$ROOT" timeout 200 python3 -m pytest -q -p no:cacheprovider -m "not slow" \
    tests/test_writer_threads.py tests/test_survey.py tests/test_scan.py 2>&1 | tail -15
  echo "all done at $((SECONDS - start)) s"
}

case "${1:-}" in
  prepare) shift; prepare "$@" ;;
  run) run ;;
  *) echo "usage: $0 prepare BASE [CPU_MANIFEST] | run" >&2; exit 2 ;;
esac
