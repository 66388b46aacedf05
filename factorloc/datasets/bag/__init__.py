"""Robot bags (ROS 1, ROS 2, MCAP; pure-Python ``rosbags``) → factorloc's types and scenarios.

- :mod:`~factorloc.datasets.bag.read` — the topics of a bag and a first pass over it (odometry, TF, intrinsics, scans, stamps);
- :mod:`~factorloc.datasets.bag.frames` — rigid 3D transforms and the bag's TF tree;
- :mod:`~factorloc.datasets.bag.images` — ``Image``/``CompressedImage``/``CameraInfo`` → :class:`~factorloc.CameraImage`;
- :mod:`~factorloc.datasets.bag.sensors` — the sensors of a time in the robot frame (:class:`BagSensors`);
- :mod:`~factorloc.datasets.bag.convert` — a whole bag → a :class:`~factorloc.datasets.Scenario` (:func:`convert_bag`,
  what ``factorloc convert`` runs).
"""

from factorloc.datasets.bag.convert import Conversion, ConversionReport, ConvertConfig, convert_bag
from factorloc.datasets.bag.frames import Rigid3, TransformTree
from factorloc.datasets.bag.images import CameraIntrinsics, camera_image, compressed_image_to_bgr, image_to_bgr
from factorloc.datasets.bag.read import BagTopic, SensorTopics, bag_topics, read_bag_index, resolve_topics
from factorloc.datasets.bag.sensors import BagSensors, SensorConfig, open_bag_sensors

__all__ = [
    "BagSensors",
    "BagTopic",
    "CameraIntrinsics",
    "Conversion",
    "ConversionReport",
    "ConvertConfig",
    "Rigid3",
    "SensorConfig",
    "SensorTopics",
    "TransformTree",
    "bag_topics",
    "camera_image",
    "compressed_image_to_bgr",
    "convert_bag",
    "image_to_bgr",
    "open_bag_sensors",
    "read_bag_index",
    "resolve_topics",
]
