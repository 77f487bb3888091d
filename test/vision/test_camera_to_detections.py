"""The real camera driver (``camera``, reading a Motion-JPEG video file written here of one
drawn scene) and the detector in one executor: the driver's frames come back as detections
with the frames' own stamps and the scene's buoys.
"""

from __future__ import annotations

import cv2
import numpy as np
from rclpy.parameter import Parameter
from support.nodes import add, probe, TIMEOUT

from enbarr_core.vision.detection import Detection, iou
from enbarr_core.vision.detector_node import DetectorNode
from enbarr_core.vision.synthetic import scene
from enbarr_interfaces import convert, topics
from enbarr_interfaces.detections import from_cloud
from enbarr_plugins.camera.opencv_camera import CameraNode


def test_camera_frames_come_back_as_detections_with_their_stamps(context, executor, spin,
                                                                 tmp_path):
    img, truth = scene(np.random.default_rng(8), buoys=3)
    path = str(tmp_path / 'buoys.avi')
    writer = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*'MJPG'), 15.0, (640, 480))
    assert writer.isOpened()
    for _ in range(5):
        writer.write(img)
    writer.release()
    camera = add(executor, CameraNode(context=context, parameter_overrides=[
        Parameter('device', value=path), Parameter('frame_rate', value=15.0)]))
    add(executor, DetectorNode(context=context))
    p = probe(context, executor)
    image_stamps: set[int] = set()
    clouds = []
    p.create_subscription(topics.CAMERA_IMAGE.msg_type, topics.CAMERA_IMAGE.name,
                          lambda m: image_stamps.add(convert.stamp_to_ns(m.header.stamp)),
                          topics.CAMERA_IMAGE.qos)
    p.create_subscription(topics.DETECTIONS.msg_type, topics.DETECTIONS.name, clouds.append,
                          topics.DETECTIONS.qos)
    camera.start()

    def answered() -> bool:   # three frames answered, and the probe has those frames too
        stamps = {convert.stamp_to_ns(c.header.stamp) for c in clouds[:3]}
        return len(stamps) == 3 and stamps <= image_stamps

    try:
        assert spin(executor, answered, TIMEOUT)
    finally:
        camera.stop()
    for cloud in clouds[:3]:
        assert cloud.header.frame_id == topics.CAMERA_OPTICAL_FRAME
        found = [Detection(int(r['class_id']), float(r['score']), float(r['x_min']),
                           float(r['y_min']), float(r['x_max']), float(r['y_max']))
                 for r in from_cloud(cloud)]
        assert len(found) == len(truth)
        for t in truth:
            tb = Detection(t.class_id, 1.0, t.x_min, t.y_min, t.x_max, t.y_max)
            assert any(d.class_id == t.class_id and iou(d, tb) > 0.8 for d in found), t
