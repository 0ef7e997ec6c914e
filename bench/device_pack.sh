#!/usr/bin/env bash
# Packs what the GPU checks need on a device machine (bench/device_check.sh) into .device/ (git
# ignores it; the device tool carries it: carry=[".device"]). The device image has Python 3.12
# with NumPy, SciPy, aiohttp, click, matplotlib, pandas, Pillow, h5py and requests, and no
# network: the packages grassd imports that it lacks travel as one archive of their installed
# files, at the versions of this checkout's .venv, for CPython 3.12 on x86-64 Linux. Installed
# and xz-compressed they fit the tool's 64 MiB with the tree (the wheels alone would not:
# Taichi's is 56 MB). Left out of the archive: what grassd never loads (Taichi's C API library
# and examples, pvlib's data files and tests, the coverage report colour-science 0.4.7 ships).
# The shared HDRIs travel too (../shared does not). Takes about 3 minutes on 2 cores.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
py=${PYTHON:-$root/.venv/bin/python}
hdri=$(cd "$root" && "$py" -c "from bench import HDRI_DIR; print(HDRI_DIR)")
out=$root/.device
# distributions the studio, grassd fit and the backend bench import that the image lacks
dists=(taichi dill OpenEXR colour-science pvlib pytz rawpy tomli_w cobs)
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
platforms=()
for p in manylinux_2_28_x86_64 manylinux_2_27_x86_64 manylinux_2_17_x86_64 \
         manylinux2014_x86_64 manylinux1_x86_64; do
  platforms+=(--platform "$p")
done
pins=()
for d in "${dists[@]}"; do
  pins+=("$d==$("$py" -c "import importlib.metadata as m, sys; print(m.version(sys.argv[1]))" "$d")")
done
# cobs has no CPython 3.12 wheel after 1.2.0 (grassd needs >= 1.2): that one, whatever the .venv has
pins=("${pins[@]/#cobs==*/cobs==1.2.0}")
echo "device_pack: ${pins[*]}"
"$py" -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 \
  --implementation cp "${platforms[@]}" -d "$work/wheels" "${pins[@]}"
"$py" -m pip install -q --no-deps --no-index --no-compile --only-binary=:all: \
  --python-version 3.12 --implementation cp "${platforms[@]}" --target "$work/site" \
  "$work"/wheels/*.whl
rm -rf "$work"/site/taichi/_lib/c_api "$work"/site/taichi/examples "$work"/site/pvlib/data \
       "$work"/site/pvlib/tests "$work"/site/colour/htmlcov "$work"/site/bin
mkdir -p "$out"
tar -C "$work/site" -cf - . | xz -T0 -6 > "$out/site.tar.xz"
rm -rf "$out/hdri"
if [ -d "$hdri" ]; then
  mkdir -p "$out/hdri"
  cp "$hdri"/*.exr "$out/hdri/"
else
  echo "device_pack: no HDRIs at $hdri; the studio and fit checks will skip" >&2
fi
du -sh "$out"/* | sed 's/^/device_pack: /'
