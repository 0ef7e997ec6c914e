#!/usr/bin/env bash
# The GPU checks, as one script for a session lent a device machine (the studio runs the
# same with --arch gpu; the GPU backend agrees with the CPU on the same seeds). Pack first
# (here): bench/device_pack.sh. Then, through the device tool:
#   run(command="bash bench/device_check.sh", carry=[".device"], timeout_s=480)
# Checks (arguments; these three by default, in this order): backend (bench_backend: both
# arches, the same seeds), studio (bench_studio with --arch gpu), fit (bench_fit with --arch
# gpu); studio-cpu (bench_studio with --arch cpu on the same machine) when named. Each has its
# own time limit in seconds (CHECK_S_<NAME> overrides, e.g. CHECK_S_STUDIO_GPU); the default
# three take at most about 7 minutes, so that one call and the machine's start leave a rerun
# inside a session's 15 minutes of device time. A check that runs out is reported and the next
# runs; the exit status is 1 if any failed. Logs go to $OUT (the tool brings them back), else
# to .device/out.
set -uo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
out=${OUT:-$root/.device/out}
mkdir -p "$out"
site=${DEVICE_SITE:-/tmp/grassd-site}
py=${PYTHON:-python3}
cd "$root"
if [ ! -f .device/site.tar.xz ]; then
  echo "device_check: .device/site.tar.xz missing: run bench/device_pack.sh here, carry .device"
  exit 2
fi
t0=$(date +%s)
rm -rf "$site" && mkdir -p "$site"
tar -C "$site" -xJf .device/site.tar.xz || { echo "device_check: unpacking failed"; exit 2; }
# grassd from the tree, its sub-packages mapped as pyproject.toml's package-dir (and the
# editable install) maps them: a finder after Python's own, loaded at start-up.
cat > "$site/sitecustomize.py" <<'PY'
import importlib.util
import os
import sys
import tomllib

_TREE = os.environ["GRASSD_TREE"]
with open(os.path.join(_TREE, "pyproject.toml"), "rb") as f:
    _DIRS = tomllib.load(f)["tool"]["setuptools"]["package-dir"]


class _GrassdTree:
    @staticmethod
    def find_spec(name, path=None, target=None):
        if name == "grassd" or name not in _DIRS:
            return None
        init = os.path.join(_TREE, _DIRS[name], "__init__.py")
        return importlib.util.spec_from_file_location(
            name, init, submodule_search_locations=[os.path.dirname(init)])


sys.meta_path.append(_GrassdTree)
PY
export GRASSD_TREE="$root" PYTHONPATH="$site:$root${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1
export GRASSD_BENCH_HDRI_DIR="$root/.device/hdri"
export GRASSD_BENCH_STUDIO_ROUNDS=1 GRASSD_BENCH_STUDIO_PROGRESS=1
echo "device_check: unpacked in $(( $(date +%s) - t0 )) s; $("$py" --version)"
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader 2>/dev/null \
  | sed 's/^/device_check: GPU /'
timeout -k 5 60 "$py" -c \
  "import grassd.sim.backend as b; print('device_check: Taichi gpu runs on', b.init('gpu'))" \
  2>&1 | grep -v '^\[Taichi\]' | tail -1

check() {  # name, seconds, command...
  local name=$1 limit=$2; shift 2
  local var="CHECK_S_${name^^}"; var=${var//-/_}; limit=${!var:-$limit}
  local start=$(date +%s)
  echo "device_check: $name (at most $limit s)"
  timeout -k 10 "$limit" "$@" > "$out/$name.log" 2>&1
  local rc=$?
  [ $rc -eq 0 ] || fail=1
  grep -v '^\[Taichi\]' "$out/$name.log" | tail -40
  echo "device_check: $name rc $rc in $(( $(date +%s) - start )) s"
}

fail=0
checks=("$@")
[ ${#checks[@]} -eq 0 ] && checks=(backend studio fit)
for c in "${checks[@]}"; do
  case $c in
    backend) check backend 120 "$py" -m bench backend ;;
    studio) GRASSD_BENCH_ARCH=gpu check studio-gpu 150 "$py" -m bench studio ;;
    studio-cpu) GRASSD_BENCH_ARCH=cpu check studio-cpu 120 "$py" -m bench studio ;;
    fit) GRASSD_BENCH_ARCH=gpu check fit-gpu 150 "$py" -m bench fit ;;
    *) echo "device_check: unknown check $c (backend, studio, studio-cpu, fit)"; exit 2 ;;
  esac
done
echo "device_check: all done in $(( $(date +%s) - t0 )) s"
exit $fail
