#!/usr/bin/env python3
"""Template: an OpenPCDet or MMDetection3D model served over mlod-detector/1.

    mlod window --detector "pp=python3 examples/detectors/openpcdet_template.py \
        --framework openpcdet --cfg cfgs/lyft_models/cbgs_pp_multihead.yaml --ckpt pp.pth"

Fill in load_model() and infer() for your checkout (marked TODO); everything mlod needs — the
frame, the fields, the box convention — is handled by to_model_points() and to_mlod_boxes(), which
run without either framework (`--framework none` serves no boxes: a check of the plumbing).

Conventions (docs/external.md has the protocol):

  what                 mlod sends / expects                 OpenPCDet                       MMDetection3D (>= 1.0)
  point frame          base = LIDAR_TOP sensor frame,       the LiDAR frame of the dataset  the LiDAR frame (LiDARPoints)
                       x fwd, y left, z up                  (Lyft/nuScenes: LIDAR_TOP)
  z origin             the LiDAR (ground ~ -1.7 m)          the LiDAR (KITTI models expect  the LiDAR
                                                            ground ~ -1.73 m)
  intensity            0-255                                as the dataset stores it: Lyft  nuScenes/Lyft 0-255; KITTI 0-1:
                                                            and nuScenes 0-255, KITTI 0-1   scale with --intensity-scale
  extra point fields   lidar id, tr(Xi)                     drop them (or add to            drop them (load_dim/use_dim)
                                                            POINT_FEATURE_ENCODING)
  nuScenes time lag    (single sweep)                       add a 0 column if the model     add a 0 column (use_dim 5)
                                                            uses 5 features
  box centre           geometric centre                     geometric centre                bottom centre (origin (0.5,0.5,0)):
                                                                                            z_centre = z_bottom + h/2
  box size             [l, w, h], l along the heading       [dx, dy, dz] = [l, w, h]        [l, w, h] (dims)
  yaw                  about +z, 0 = +x                      about +z, 0 = +x                about +z, 0 = +x (>= 1.0;
                                                                                            0.x used -yaw - pi/2)
  categories           Lyft names: car, pedestrian, ...      the cfg's CLASS_NAMES           the cfg's class_names
"""
import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from mlod_detector import serve  # noqa: E402


def to_model_points(points, intensity_scale, time_column):
    """mlod's (N, 6) base-frame points -> the (N, 4 or 5) array x, y, z, intensity[, 0] a model takes."""
    import numpy as np

    out = points[:, :4].astype(np.float32, copy=True)
    out[:, 3] *= intensity_scale
    if time_column:
        out = np.concatenate([out, np.zeros((len(out), 1), np.float32)], axis=1)
    return out


def to_mlod_boxes(boxes, scores, labels, class_names, bottom_origin, min_score):
    """(M, 7) x, y, z, l, w, h, yaw boxes + scores + 0-based labels -> mlod-detector/1 boxes."""
    out = []
    for b, s, k in zip(boxes, scores, labels):
        if s < min_score:
            continue
        x, y, z, l, w, h, yaw = (float(v) for v in b[:7])
        if bottom_origin:
            z += h / 2.0
        out.append(dict(category=class_names[int(k)].lower(), score=float(s), center=[x, y, z],
                        size_lwh=[l, w, h], yaw=yaw))
    return out


def load_model(args):
    """TODO: build the model from args.cfg and args.ckpt, on args.device, in eval mode."""
    if args.framework == "openpcdet":
        # from pcdet.config import cfg, cfg_from_yaml_file
        # from pcdet.models import build_network, load_data_to_gpu
        # cfg_from_yaml_file(args.cfg, cfg)
        # model = build_network(cfg.MODEL, len(cfg.CLASS_NAMES), dataset=<a DatasetTemplate for cfg>)
        # model.load_params_from_file(args.ckpt, logger=<logger>, to_cpu=True); model.cuda().eval()
        raise NotImplementedError("fill in load_model() for OpenPCDet")
    if args.framework == "mmdet3d":
        # from mmdet3d.apis import init_model
        # return init_model(args.cfg, args.ckpt, device=args.device)
        raise NotImplementedError("fill in load_model() for MMDetection3D")
    return None


def infer(model, args, points):
    """TODO: run the model on the (N, 4|5) points; return (boxes (M, 7), scores (M,), labels (M,))."""
    import numpy as np

    if model is None:
        return np.zeros((0, 7)), np.zeros(0), np.zeros(0, int)
    # OpenPCDet: batch = dataset.prepare_data({"points": points, "frame_id": 0}); collate; load_data_to_gpu;
    #   pred = model(batch)[0][0]; boxes, scores, labels = pred["pred_boxes"], pred["pred_scores"], pred["pred_labels"] - 1
    # MMDetection3D: from mmdet3d.apis import inference_detector (with a points file or LiDARPoints);
    #   r = result.pred_instances_3d; boxes = r.bboxes_3d.tensor[:, :7]; scores = r.scores_3d; labels = r.labels_3d
    raise NotImplementedError("fill in infer()")


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--framework", choices=["openpcdet", "mmdet3d", "none"], default="none")
    p.add_argument("--cfg")
    p.add_argument("--ckpt")
    p.add_argument("--device", default="cuda:0")
    p.add_argument("--classes", default="car", help="comma-separated class names, in the model's label order")
    p.add_argument("--intensity-scale", type=float, default=1.0, help="1 for Lyft/nuScenes models, 1/255 for KITTI")
    p.add_argument("--time-column", action="store_true", help="append a zero time-lag column (nuScenes 5-feature models)")
    p.add_argument("--min-score", type=float, default=0.05)
    args = p.parse_args()
    class_names = args.classes.split(",")
    model = load_model(args)
    bottom = args.framework == "mmdet3d"

    def detect(_request, points):
        boxes, scores, labels = infer(model, args, to_model_points(points, args.intensity_scale, args.time_column))
        return to_mlod_boxes(boxes, scores, labels, class_names, bottom, args.min_score)

    serve(detect)


if __name__ == "__main__":
    main()
