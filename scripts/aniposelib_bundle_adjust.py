#!/usr/bin/env python3
"""aniposelib's own bundle adjustment of the mouse-outdoor 12-camera rig: the reference for
`softcap capture calibrate` (docs/capture.md, "Calibration"). Run it through
`scripts/aniposelib-bundle-adjust`, which installs aniposelib 0.8.0 into .venv-aniposelib:

    scripts/aniposelib-bundle-adjust ../shared/data/aniposelib/mouse-outdoor fixtures/aniposelib [--full]

`CameraGroup.bundle_adjust_iter` runs with its defaults (6 iterations of scipy `least_squares`
(trf, lsmr, sparse Jacobian) on resampled points, robust threshold schedule 15 → 1, 8 parameters per
camera: Rodrigues rotation, translation, one focal length, k1 — its `set_params` zeroes the other
distortion coefficients). The points are the fixture subset `p2d[:, ::59][:, :3000]` (2,998 points),
or all 176,868 with `--full`; the cameras are in numeric `cam_N` order (fixtures/aniposelib/README.md).
numpy's global generator is seeded (0) because `resample_points` draws from it.

Writes into the output folder:
  bundle_adjust_calibration.toml  the refined rig, aniposelib's own `CameraGroup.dump` format
  bundle_adjust_reference.toml    before/after median per-point reprojection error with aniposelib's
                                  triangulation (`triangulate`, then `reprojection_error(mean=True)`:
                                  per point the mean over its views of the pixel error), and the
                                  wall time of `bundle_adjust_iter`
"""
import os
import sys
import time

import aniposelib  # noqa: F401  (version recorded below)
import cv2
import numpy as np
import scipy
import toml
from aniposelib.cameras import CameraGroup

SUBSET_STEP = 59
SUBSET_SIZE = 3000


def median_point_error(cgroup, p2d):
    p3d = cgroup.triangulate(p2d, undistort=True)
    per_point = cgroup.reprojection_error(p3d, p2d, mean=True)
    return float(np.nanmedian(per_point))


def main():
    src, out = sys.argv[1], sys.argv[2]
    full = '--full' in sys.argv[3:]
    calib = toml.load(os.path.join(src, 'calibration_right_4_10_2026_adjusted.toml'))
    keys = sorted((k for k in calib if k != 'metadata'), key=lambda k: int(k.split('_')[1]))
    cgroup = CameraGroup.from_dicts([calib[k] for k in keys])
    p2d = np.load(os.path.join(src, 'points_right_4_10_2026_sub.npz'))['p2d']
    assert p2d.shape[0] == len(keys)
    if not full:
        p2d = p2d[:, np.arange(0, p2d.shape[1], SUBSET_STEP)[:SUBSET_SIZE]]
    observations = int(np.sum(~np.isnan(p2d[:, :, 0])))
    before = median_point_error(cgroup, p2d)
    print(f'{p2d.shape[1]} points, {observations} observations; median per-point error before: {before:.3f} px',
          flush=True)
    np.random.seed(0)
    t0 = time.perf_counter()
    cgroup.bundle_adjust_iter(p2d)
    seconds = time.perf_counter() - t0
    after = median_point_error(cgroup, p2d)
    print(f'after bundle_adjust_iter: {after:.3f} px in {seconds:.1f} s', flush=True)
    os.makedirs(out, exist_ok=True)
    suffix = '_full' if full else ''
    cgroup.dump(os.path.join(out, f'bundle_adjust_calibration{suffix}.toml'))
    with open(os.path.join(out, f'bundle_adjust_reference{suffix}.toml'), 'w') as f:
        f.write('# written by scripts/aniposelib_bundle_adjust.py; do not edit\n')
        f.write('aniposelib = "0.8.0"\n')
        f.write(f'numpy = "{np.__version__}"\nscipy = "{scipy.__version__}"\nopencv = "{cv2.__version__}"\n')
        f.write(f'points_rule = "{"all of p2d" if full else f"p2d[:, ::{SUBSET_STEP}][:, :{SUBSET_SIZE}]"}"\n')
        f.write(f'points = {p2d.shape[1]}\nobservations = {observations}\n')
        f.write(f'median_point_error_before_px = {before}\n')
        f.write(f'median_point_error_after_px = {after}\n')
        f.write(f'bundle_adjust_iter_seconds = {seconds:.1f}\n')
        f.write(f'cpu_count = {os.cpu_count()}\n')


if __name__ == '__main__':
    main()
