"""fusion/scene: the trocar at the RCM and the tip's trail, as Foxglove's 3D panel reads them."""

from __future__ import annotations

import numpy as np
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

from services.fusion.live.scene import SceneTrail
from tiplog import topics


def test_trail_keeps_the_window_at_its_point_rate_and_the_trocar_at_the_rcm():
    rcm = np.array([0.65, 0.0, 0.30])
    trail = SceneTrail(rcm, trail_s=1.0, point_period_ns=50_000_000)
    for k in range(400):  # 2 s of states at 200 Hz
        trail.add(k * 5_000_000, np.array([0.7, 0.001 * k, 0.2]))
    msg = SceneUpdate.FromString(trail.message(2_000_000_000).SerializeToString())
    ents = {e.id: e for e in msg.entities}
    assert set(ents) == {"trocar", "tip_trail"} and all(e.frame_id == "base" for e in ents.values())
    s = ents["trocar"].spheres[0].pose.position
    assert (s.x, s.y, s.z) == tuple(rcm)
    pts = np.array([(p.x, p.y, p.z) for p in ents["tip_trail"].lines[0].points])
    assert 20 <= len(pts) <= 21  # the last 1 s at 20 points a second
    assert pts[-1, 1] == 0.001 * 390 and np.all(np.diff(pts[:, 1]) > 0)
    assert topics.message_type("fusion/scene") is SceneUpdate
