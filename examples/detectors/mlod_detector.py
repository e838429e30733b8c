"""The detector side of mlod-detector/1 (docs/external.md), for adapters to import.

    from mlod_detector import serve
    serve(lambda request, points: [dict(category="car", score=0.9, center=[x, y, z],
                                         size_lwh=[l, w, h], yaw=yaw), ...])

`points` is an (N, 6) float32 numpy array (x, y, z, intensity, lidar, trace; base frame) when
numpy is installed, else a flat array.array('f') of N*6 values. An exception in the detect
function becomes an error answer for that frame (mlod stops the case and names it); stdout is
reserved for answers, so anything printed goes to stderr.
Only the standard library is needed; numpy is used when present.
"""
import array
import json
import sys
import traceback

PROTOCOL = "mlod-detector/1"
FIELDS = ["x", "y", "z", "intensity", "lidar", "trace"]


def read_points(request):
    """The request's points file: (N, 6) float32 with numpy, else a flat array('f')."""
    n = int(request["num_points"])
    try:
        import numpy as np
    except ImportError:
        a = array.array("f")
        with open(request["points_file"], "rb") as f:
            a.frombytes(f.read(n * 24))
        if sys.byteorder != "little":
            a.byteswap()
        return a
    return np.fromfile(request["points_file"], dtype="<f4", count=n * 6).reshape(n, 6)


def serve(detect):
    """Answers every request on stdin with detect(request, points) until stdin closes."""
    out = sys.stdout
    sys.stdout = sys.stderr  # a stray print() must not corrupt the answers
    for line in sys.stdin:
        if not line.strip():
            continue
        request = json.loads(line)
        token = request.get("sample_token", "")
        if request.get("protocol") != PROTOCOL or request.get("fields") != FIELDS:
            answer = {"sample_token": token, "error": "unsupported request: %s" % line.strip()[:200]}
        else:
            try:
                boxes = detect(request, read_points(request))
                answer = {"sample_token": token, "boxes": [normalise(b) for b in boxes]}
            except Exception as e:  # noqa: BLE001 - every failure becomes an error answer
                traceback.print_exc(file=sys.stderr)
                answer = {"sample_token": token, "error": "%s: %s" % (type(e).__name__, e)}
        out.write(json.dumps(answer) + "\n")
        out.flush()


def normalise(b):
    """A box as plain JSON numbers (numpy scalars and arrays become floats and lists)."""
    return {
        "category": str(b["category"]),
        "score": float(b["score"]),
        "center": [float(v) for v in b["center"]],
        "size_lwh": [float(v) for v in b["size_lwh"]],
        "yaw": float(b["yaw"]),
    }
