"""`fusion/scene`: what Foxglove's 3D panel cannot draw from transforms alone, as a Foxglove
`SceneUpdate` in the base frame: the registered trocar (a sphere at the RCM) and the tip's
recent trail (a line strip through the estimated tips of the last `TRAIL_S` seconds).
"""

from __future__ import annotations

from collections import deque

import numpy as np
from foxglove_schemas_protobuf.LinePrimitive_pb2 import LinePrimitive
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

FRAME = "base"
TRAIL_S = 10.0
TRAIL_POINT_PERIOD_NS = 50_000_000  # 20 points a second
SCENE_PERIOD_NS = 200_000_000  # published at 5 Hz
TROCAR_DIAMETER_M = 0.008


class SceneTrail:
    """The tips of the last `trail_s` seconds, one point per `point_period_ns`; `message()`
    gives the SceneUpdate of the trail and the trocar."""

    def __init__(self, rcm_base_m: np.ndarray, trail_s: float = TRAIL_S, point_period_ns: int = TRAIL_POINT_PERIOD_NS):
        self.rcm_base_m = np.asarray(rcm_base_m, float)
        self._window_ns = int(trail_s * 1e9)
        self._period_ns = int(point_period_ns)
        self._points: deque[tuple[int, tuple[float, float, float]]] = deque()

    def add(self, stamp_ns: int, p_tip_base_m: np.ndarray) -> None:
        if self._points and stamp_ns - self._points[-1][0] < self._period_ns:
            return
        self._points.append((int(stamp_ns), tuple(float(c) for c in p_tip_base_m)))
        while self._points and stamp_ns - self._points[0][0] > self._window_ns:
            self._points.popleft()

    def __len__(self) -> int:
        return len(self._points)

    def message(self, stamp_ns: int) -> SceneUpdate:
        msg = SceneUpdate()
        trocar = msg.entities.add()
        trocar.timestamp.FromNanoseconds(int(stamp_ns))
        trocar.frame_id, trocar.id = FRAME, "trocar"
        sphere = trocar.spheres.add()
        sphere.pose.position.x, sphere.pose.position.y, sphere.pose.position.z = self.rcm_base_m.tolist()
        sphere.pose.orientation.w = 1.0
        sphere.size.x = sphere.size.y = sphere.size.z = TROCAR_DIAMETER_M
        sphere.color.r, sphere.color.g, sphere.color.b, sphere.color.a = 1.0, 0.6, 0.0, 0.8
        trail = msg.entities.add()
        trail.timestamp.FromNanoseconds(int(stamp_ns))
        trail.frame_id, trail.id = FRAME, "tip_trail"
        line = trail.lines.add()
        line.type = LinePrimitive.LINE_STRIP
        line.pose.orientation.w = 1.0
        line.thickness, line.scale_invariant = 2.0, True  # pixels
        line.color.r, line.color.g, line.color.b, line.color.a = 0.1, 0.8, 1.0, 1.0
        for _t, (x, y, z) in self._points:
            pt = line.points.add()
            pt.x, pt.y, pt.z = x, y, z
        return msg
