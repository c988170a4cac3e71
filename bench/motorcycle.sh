#!/usr/bin/env bash
# Disparity of Middlebury 2014's Motorcycle pair as Debian's python3-skimage installs it
# (quarter size, 741x500, disparities 7..60), scored against its ground truth: bad > 2 px,
# invalid counted as bad, for each matcher. The ground truth (an .npz) is converted to a PFM in a
# temporary folder; nothing is written to the repository.
# Usage: bench/motorcycle.sh [WORKSPACE] [ALGORITHM...]   (default: census_sgm sad bm sgbm)
set -euo pipefail
ws=${1:-$(PATH=/usr/bin:$PATH "$(dirname "$0")/../scripts/setup" | tail -n 1)}
shift || true
algorithms=("$@")
[ ${#algorithms[@]} -gt 0 ] || algorithms=(census_sgm sad bm sgbm)
data=$(/usr/bin/python3 -c 'import os, skimage; print(os.path.join(os.path.dirname(skimage.__file__), "data"))' 2>/dev/null) || {
  echo "motorcycle: python3-skimage is not installed (apt install python3-skimage)" >&2; exit 1; }
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
/usr/bin/python3 - "$data/motorcycle_disp.npz" "$tmp/gt.pfm" <<'PY'
import sys
import numpy as np
d = np.load(sys.argv[1])["arr_0"].astype(np.float32)
d[~np.isfinite(d)] = 0  # no ground truth
with open(sys.argv[2], "wb") as f:
    f.write(b"Pf\n%d %d\n-1.0\n" % (d.shape[1], d.shape[0]))
    f.write(np.flipud(d).astype("<f4").tobytes())  # PFM: rows bottom to top, little endian
PY
tool="$ws/devel/lib/embedded_calibration_stereo/disparity_images"
for a in "${algorithms[@]}"; do
  printf '%-12s ' "$a"
  "$tool" --left "$data/motorcycle_left.png" --right "$data/motorcycle_right.png" \
    --out "$tmp/d.pfm" --gt "$tmp/gt.pfm" --gt-scale 1 --algorithm "$a" | tail -n 1
done
