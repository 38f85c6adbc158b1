#!/usr/bin/env python3
"""aniposelib's own triangulation of the mouse-outdoor 12-camera data, as the reference figure for
softcap's DLT + Levenberg–Marquardt triangulation (issue 6), and the fixture subset softcap's test uses.

    python3 -m venv /tmp/anipose-venv && /tmp/anipose-venv/bin/pip install aniposelib==0.8.0
    /tmp/anipose-venv/bin/python scripts/aniposelib_reference.py \
        ../shared/data/aniposelib/mouse-outdoor fixtures/aniposelib

Writes into the output folder:
  calibration.toml  the calibration, unchanged
  points.csv        point,camera,u,v for every 59th point of p2d (2,998 points), camera = TOML section
  reference.toml    aniposelib's figures: CameraGroup.triangulate (undistort=True: cv2.undistortPoints,
                    then the DLT of triangulate_simple, SVD of the stacked equations) and
                    CameraGroup.reprojection_error(mean=True) (per point, the mean over its views of
                    the pixel reprojection error through cv2.projectPoints), median over the points.
"""
import os
import shutil
import sys
import time

import aniposelib
import cv2
import numpy as np
from aniposelib.cameras import CameraGroup

SUBSET_STEP = 59
SUBSET_SIZE = 3000


def figures(cgroup, p2d):
    t0 = time.perf_counter()
    p3d = cgroup.triangulate(p2d, undistort=True)
    seconds = time.perf_counter() - t0
    per_point = cgroup.reprojection_error(p3d, p2d, mean=True)
    per_obs = np.linalg.norm(cgroup.reprojection_error(p3d, p2d), axis=2)
    per_obs = per_obs[~np.isnan(per_obs)]
    return {
        'points': int(p2d.shape[1]),
        'observations': int(per_obs.size),
        'median_point_mean_error_px': float(np.nanmedian(per_point)),
        'median_observation_error_px': float(np.median(per_obs)),
        'triangulate_seconds': round(seconds, 3),
    }


def main():
    src, out = sys.argv[1], sys.argv[2]
    calib = os.path.join(src, 'calibration_right_4_10_2026_adjusted.toml')
    import toml
    calib_dict = toml.load(calib)
    # p2d's first axis follows the cameras' numeric index (cam_0, cam_1, ..., cam_11). Note that
    # CameraGroup.load would order them by the sorted section keys (cam_0, cam_1, cam_10, cam_11,
    # cam_2, ...): with that pairing the median error is ~169 px against ~48 px, and a search over
    # camera permutations by epipolar consistency picks the numeric order. So the group is built
    # with CameraGroup.from_dicts in numeric order; the lexicographic figure is recorded as well.
    keys = sorted((k for k in calib_dict if k != 'metadata'), key=lambda k: int(k.split('_')[1]))
    cgroup = CameraGroup.from_dicts([calib_dict[k] for k in keys])
    p2d = np.load(os.path.join(src, 'points_right_4_10_2026_sub.npz'))['p2d']
    assert p2d.shape[0] == len(keys) == len(cgroup.cameras)
    subset = np.arange(0, p2d.shape[1], SUBSET_STEP)[:SUBSET_SIZE]
    full = figures(cgroup, p2d)
    sub = figures(cgroup, p2d[:, subset])
    lexicographic = figures(CameraGroup.load(calib), p2d[:, subset])
    os.makedirs(out, exist_ok=True)
    shutil.copy(calib, os.path.join(out, 'calibration.toml'))
    with open(os.path.join(out, 'points.csv'), 'w') as f:
        f.write('point,camera,u,v\n')
        for i, p in enumerate(subset):
            for c, key in enumerate(keys):
                u, v = p2d[c, p]
                if not np.isnan(u):
                    f.write(f'{i},{key},{u:.6f},{v:.6f}\n')
    with open(os.path.join(out, 'reference.toml'), 'w') as f:
        f.write('# written by scripts/aniposelib_reference.py; do not edit\n')
        f.write(f'aniposelib = "{aniposelib.__version__ if hasattr(aniposelib, "__version__") else "0.8.0"}"\n')
        f.write(f'numpy = "{np.__version__}"\nopencv = "{cv2.__version__}"\n')
        f.write(f'subset_rule = "p2d[:, ::{SUBSET_STEP}][:, :{SUBSET_SIZE}]"\n')
        for name, d in (('subset', sub), ('full', full), ('subset_lexicographic_camera_order', lexicographic)):
            f.write(f'\n[{name}]\n')
            for k, v in d.items():
                f.write(f'{k} = {v}\n')
    print('subset', sub)
    print('full', full)


if __name__ == '__main__':
    main()
