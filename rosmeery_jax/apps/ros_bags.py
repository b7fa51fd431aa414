"""ROS 2 bags without ROS (docs/record.md, docs/evaluate.md), read and written with rosbags.

Out: :class:`BagStreams` writes one recorded run as a ROS 2 bag (MCAP or SQLite 3) in the
standard message types and REP 103 / 105 frames: colour and depth images with their
``CameraInfo`` in the camera's optical frame, the ``LaserScan``, wheel odometry
(``nav_msgs/Odometry``, odom -> base_link) and the ground truth on its own topic, ``/tf``
(map -> odom -> base_link) and ``/tf_static`` (base_link -> camera_link ->
camera_optical_frame, base_link -> laser), ``/clock`` and the detector's boxes
(``vision_msgs/Detection2DArray``, whose definitions the bag carries).

In: :func:`read_maps` turns the ``sensor_msgs/PointCloud2`` maps a ROS mapper published
into the semantic maps ``rosmeery evaluate`` scores: ``x y z`` and an instance field
(``instance``, ``instance_id`` or ``object_id``), optional ``label`` (taxonomy index, -1
none) and ``confidence`` fields, instance labels from a ``std_msgs/String`` JSON topic (the
format of a map's JSON: ``{"objects": [{"id", "label", "confidence"}]}``), each message's
header stamp its time.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from rosmeery_jax.core.errors import InputError

FORMATS = ("tum", "mcap", "sqlite3")
HINT = "rosbags is missing: pip install 'rosmeery-jax[ros]' (or pip install rosbags)"
FRAMES = {"map": "map", "odom": "odom", "base": "base_link", "camera": "camera_link",
          "optical": "camera_optical_frame", "laser": "laser"}
INSTANCE_FIELDS = ("instance", "instance_id", "object_id")

# vision_msgs 4.x (ROS 2 Humble): not in rosbags' stores, so the bag carries their definitions
VISION_MSGS = {
    "vision_msgs/msg/Point2D": "float64 x\nfloat64 y\n",
    "vision_msgs/msg/Pose2D": "vision_msgs/Point2D position\nfloat64 theta\n",
    "vision_msgs/msg/BoundingBox2D": "vision_msgs/Pose2D center\nfloat64 size_x\nfloat64 size_y\n",
    "vision_msgs/msg/ObjectHypothesis": "string class_id\nfloat64 score\n",
    "vision_msgs/msg/ObjectHypothesisWithPose": "vision_msgs/ObjectHypothesis hypothesis\n"
                                                "geometry_msgs/PoseWithCovariance pose\n",
    "vision_msgs/msg/Detection2D": "std_msgs/Header header\nvision_msgs/ObjectHypothesisWithPose[] results\n"
                                   "vision_msgs/BoundingBox2D bbox\nstring id\n",
    "vision_msgs/msg/Detection2DArray": "std_msgs/Header header\nvision_msgs/Detection2D[] detections\n",
}


def rosbags():
    """The rosbags modules this file uses, or one line saying how to install them."""
    try:
        from rosbags import rosbag2, typesys
    except ImportError:
        raise InputError("rosbags", "import", HINT) from None
    return rosbag2, typesys


def typestore():
    """ROS 2 Humble's message types with vision_msgs added."""
    _, typesys = rosbags()
    store = typesys.get_typestore(typesys.Stores.ROS2_HUMBLE)
    types = {}
    for name, text in VISION_MSGS.items():
        types.update(typesys.get_types_from_msg(text, name))
    store.register(types)
    return store


def map_to_odom(true_pose, odom_pose) -> np.ndarray:
    """The planar transform (x, y, yaw) map -> odom that makes map -> odom -> base_link the
    true pose: T_map_odom = T_map_base inverse(T_odom_base) (REP 105). The identity while
    the odometry is exact; with drift, the rotation by the heading error about odom's
    origin, then the shift that carries the odometry's position onto the true one."""
    true_pose, odom_pose = np.asarray(true_pose, np.float64), np.asarray(odom_pose, np.float64)
    yaw = np.angle(np.exp(1j * (true_pose[2] - odom_pose[2])))
    c, s = np.cos(yaw), np.sin(yaw)
    x = true_pose[0] - (c * odom_pose[0] - s * odom_pose[1])
    y = true_pose[1] - (s * odom_pose[0] + c * odom_pose[1])
    return np.array([x, y, yaw])


def stamp_ns(t: float) -> int:
    return int(round(t * 1e9))


class BagStreams:
    """One run's streams written to a new ROS 2 bag at ``path`` (``fmt`` mcap or sqlite3).
    Call :meth:`static` once, then :meth:`step` every control step and :meth:`frame` every
    RGB-D frame, in time order; :meth:`close` ends the bag."""

    def __init__(self, path: Path, fmt: str, depth_encoding: str = "32FC1"):
        rosbag2, _ = rosbags()
        self.store = typestore()
        plugin = {"mcap": rosbag2.StoragePlugin.MCAP, "sqlite3": rosbag2.StoragePlugin.SQLITE3}[fmt]
        self.writer = rosbag2.Writer(path, version=9, storage_plugin=plugin)
        self.writer.open()
        self.depth_encoding = depth_encoding
        self.t = self.store.types
        topics = {"/clock": "rosgraph_msgs/msg/Clock", "/tf": "tf2_msgs/msg/TFMessage",
                  "/tf_static": "tf2_msgs/msg/TFMessage", "/odom": "nav_msgs/msg/Odometry",
                  "/ground_truth/odom": "nav_msgs/msg/Odometry", "/scan": "sensor_msgs/msg/LaserScan",
                  "/camera/color/image_raw": "sensor_msgs/msg/Image",
                  "/camera/color/camera_info": "sensor_msgs/msg/CameraInfo",
                  "/camera/depth/image_raw": "sensor_msgs/msg/Image",
                  "/camera/depth/camera_info": "sensor_msgs/msg/CameraInfo",
                  "/detections": "vision_msgs/msg/Detection2DArray"}
        self.conn = {}
        for topic, typ in topics.items():
            self.conn[topic] = self.writer.add_connection(topic, typ, typestore=self.store,
                                                          offered_qos_profiles=self._qos(topic))
        self.types = topics

    def _qos(self, topic: str) -> list:
        """/tf_static is latched (keep last 1, reliable, transient local), as ROS 2 tools expect."""
        if topic != "/tf_static":
            return []
        from rosbags import interfaces as i  # noqa: PLC0415 (with rosbags, found above)

        never = i.QosTime(0x7FFFFFFF, 0xFFFFFFFF)
        return [i.Qos(i.QosHistory.KEEP_LAST, 1, i.QosReliability.RELIABLE, i.QosDurability.TRANSIENT_LOCAL, never,
                      never, i.QosLiveliness.AUTOMATIC, never, False)]

    def _write(self, topic: str, t: float, msg) -> None:
        self.writer.write(self.conn[topic], stamp_ns(t), self.store.serialize_cdr(msg, self.types[topic]))

    def _header(self, t: float, frame: str):
        ns = stamp_ns(t)
        return self.t["std_msgs/msg/Header"](stamp=self.t["builtin_interfaces/msg/Time"](
            sec=ns // 10**9, nanosec=ns % 10**9), frame_id=frame)

    def _transform(self, t: float, parent: str, child: str, xyz, quat):
        T = self.t
        return T["geometry_msgs/msg/TransformStamped"](
            header=self._header(t, parent), child_frame_id=child,
            transform=T["geometry_msgs/msg/Transform"](
                translation=T["geometry_msgs/msg/Vector3"](x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2])),
                rotation=T["geometry_msgs/msg/Quaternion"](x=float(quat[0]), y=float(quat[1]), z=float(quat[2]),
                                                           w=float(quat[3]))))

    def static(self, camera, laser) -> None:
        """The fixed frames: base_link -> camera_link (the mount, pitched down), camera_link
        -> camera_optical_frame (x right, y down, z forward), base_link -> laser."""
        pitch = Rotation.from_euler("y", camera.pitch).as_quat()  # pitched down for a positive pitch
        optical = Rotation.from_matrix([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]).as_quat()
        tfs = [self._transform(0.0, FRAMES["base"], FRAMES["camera"], (camera.mount_x, 0.0, camera.mount_height),
                               pitch),
               self._transform(0.0, FRAMES["camera"], FRAMES["optical"], (0.0, 0.0, 0.0), optical),
               self._transform(0.0, FRAMES["base"], FRAMES["laser"], (0.0, 0.0, laser.height), (0, 0, 0, 1.0))]
        self._write("/tf_static", 0.0, self.t["tf2_msgs/msg/TFMessage"](transforms=tfs))

    def _odometry(self, t: float, frame: str, pose, v: float, w: float):
        T = self.t
        q = Rotation.from_euler("z", float(pose[2])).as_quat()
        cov = np.zeros(36)
        return T["nav_msgs/msg/Odometry"](
            header=self._header(t, frame), child_frame_id=FRAMES["base"],
            pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=float(pose[0]), y=float(pose[1]), z=0.0),
                orientation=T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3])), covariance=cov),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=T["geometry_msgs/msg/Twist"](
                linear=T["geometry_msgs/msg/Vector3"](x=float(v), y=0.0, z=0.0),
                angular=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=float(w))), covariance=cov))

    def step(self, t: float, odom_pose, true_pose, v: float, w: float, ranges, laser, angles) -> None:
        """One control step: /clock, /tf (map -> odom the odometry's correction,
        :func:`map_to_odom`; odom -> base_link the odometry), /odom, /ground_truth/odom, /scan."""
        T = self.t
        ns = stamp_ns(t)
        self._write("/clock", t, T["rosgraph_msgs/msg/Clock"](clock=T["builtin_interfaces/msg/Time"](
            sec=ns // 10**9, nanosec=ns % 10**9)))
        correction = map_to_odom(true_pose, odom_pose)
        q_odom = Rotation.from_euler("z", float(odom_pose[2])).as_quat()
        tfs = [self._transform(t, FRAMES["map"], FRAMES["odom"], (correction[0], correction[1], 0.0),
                               Rotation.from_euler("z", float(correction[2])).as_quat()),
               self._transform(t, FRAMES["odom"], FRAMES["base"], (odom_pose[0], odom_pose[1], 0.0), q_odom)]
        self._write("/tf", t, T["tf2_msgs/msg/TFMessage"](transforms=tfs))
        self._write("/odom", t, self._odometry(t, FRAMES["odom"], odom_pose, v, w))
        self._write("/ground_truth/odom", t, self._odometry(t, FRAMES["map"], true_pose, v, w))
        self._write("/scan", t, T["sensor_msgs/msg/LaserScan"](
            header=self._header(t, FRAMES["laser"]), angle_min=float(angles[0]), angle_max=float(angles[-1]),
            angle_increment=float(angles[1] - angles[0]), time_increment=0.0, scan_time=0.0,
            range_min=float(laser.min_range), range_max=float(laser.max_range),
            ranges=np.asarray(ranges, np.float32), intensities=np.zeros(0, np.float32)))

    def camera_info(self, t: float, intr: dict):
        T = self.t
        k = [intr["fx"], 0.0, intr["cx"], 0.0, intr["fy"], intr["cy"], 0.0, 0.0, 1.0]
        p = [intr["fx"], 0.0, intr["cx"], 0.0, 0.0, intr["fy"], intr["cy"], 0.0, 0.0, 0.0, 1.0, 0.0]
        return T["sensor_msgs/msg/CameraInfo"](
            header=self._header(t, FRAMES["optical"]), height=intr["height"], width=intr["width"],
            distortion_model="plumb_bob", d=np.zeros(5), k=np.asarray(k), r=np.eye(3).reshape(-1), p=np.asarray(p),
            binning_x=0, binning_y=0, roi=T["sensor_msgs/msg/RegionOfInterest"](
                x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))

    def frame(self, t: float, rgb: np.ndarray, depth: np.ndarray, intr: dict, detections=None,
              categories: tuple[str, ...] = ()) -> None:
        """One RGB-D frame (rgb (H, W, 3) uint8, depth (H, W) float32 metres, 0 none) with its
        CameraInfo on both cameras and, when given, its detections (label, confidence, box
        (D, 4) pixel corners) as a Detection2DArray."""
        T = self.t
        h, w = depth.shape
        self._write("/camera/color/image_raw", t, T["sensor_msgs/msg/Image"](
            header=self._header(t, FRAMES["optical"]), height=h, width=w, encoding="rgb8", is_bigendian=0,
            step=3 * w, data=np.ascontiguousarray(rgb, np.uint8).reshape(-1)))
        if self.depth_encoding == "16UC1":  # millimetres, 0: no return (REP 118)
            data, step = np.round(depth * 1000.0).clip(0, 65535).astype("<u2"), 2 * w
        else:  # metres as 32-bit floats, NaN: no return (REP 118)
            data, step = np.where(depth > 0, depth, np.nan).astype("<f4"), 4 * w
        self._write("/camera/depth/image_raw", t, T["sensor_msgs/msg/Image"](
            header=self._header(t, FRAMES["optical"]), height=h, width=w, encoding=self.depth_encoding,
            is_bigendian=0, step=step, data=np.frombuffer(data.tobytes(), np.uint8)))
        info = self.camera_info(t, intr)
        self._write("/camera/color/camera_info", t, info)
        self._write("/camera/depth/camera_info", t, info)
        if detections is not None:
            self._write("/detections", t, self._detections(t, *detections, categories))

    def _detections(self, t: float, label, conf, box, categories):
        T = self.t
        out = []
        for k, (lab, c, (x1, y1, x2, y2)) in enumerate(zip(label, conf, box)):
            hyp = T["vision_msgs/msg/ObjectHypothesisWithPose"](
                hypothesis=T["vision_msgs/msg/ObjectHypothesis"](class_id=categories[int(lab)], score=float(c)),
                pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=T["geometry_msgs/msg/Pose"](
                    position=T["geometry_msgs/msg/Point"](x=0.0, y=0.0, z=0.0),
                    orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)),
                    covariance=np.zeros(36)))
            bbox = T["vision_msgs/msg/BoundingBox2D"](center=T["vision_msgs/msg/Pose2D"](
                position=T["vision_msgs/msg/Point2D"](x=float(x1 + x2) / 2, y=float(y1 + y2) / 2), theta=0.0),
                size_x=float(x2 - x1), size_y=float(y2 - y1))
            out.append(T["vision_msgs/msg/Detection2D"](header=self._header(t, FRAMES["optical"]), results=[hyp],
                                                        bbox=bbox, id=str(k)))
        return T["vision_msgs/msg/Detection2DArray"](header=self._header(t, FRAMES["optical"]), detections=out)

    def close(self) -> None:
        self.writer.close()


# --- maps in -------------------------------------------------------------------------------

_POINT_TYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}  # PointField datatypes


def read_maps(bag: Path, topic: str, labels_topic: str | None, world: str, taxonomy) -> list:
    """The PointCloud2 maps of ``topic`` in ``bag`` (module docstring) as SemanticMaps of
    ``world``, each at its header stamp. A cloud is held to the reader contract of a PLY map
    (:func:`~rosmeery_jax.metrics.map_score.read_columns`), its layout to its header; points
    with a NaN coordinate are dropped (ROS's mark of an invalid point), so an empty or all-NaN
    cloud is an empty map. One InputError naming the bag, topic, stamp and field."""
    from rosmeery_jax.metrics.map_score import SemanticMap  # noqa: PLC0415 (evaluate's type)

    rosbag2, _ = rosbags()
    store = typestore()
    bag = Path(bag)
    try:
        reader = rosbag2.Reader(bag)
        reader.open()
    except Exception as err:  # rosbags raises several kinds on a missing, truncated or foreign bag
        raise InputError(bag, "bag", f"not a readable ROS 2 bag ({type(err).__name__}: {err})") from None
    try:
        conns, label_conns = _connections(bag, reader, topic, labels_topic)
        maps, labels = _read_messages(bag, reader, store, topic, labels_topic, conns + label_conns, taxonomy)
    finally:
        reader.close()
    if not maps:
        raise InputError(bag, topic, "holds no messages")
    out = []
    for t, (points, instance, lab, conf) in maps:
        for lt, (side_lab, side_conf) in labels:  # the side channel's latest message at or before the map
            if lt <= t + 1e-9:
                lab, conf = {**lab, **side_lab}, {**conf, **side_conf}
        out.append(SemanticMap(bag / f"{topic.strip('/').replace('/', '_')}@{t:.3f}", points, instance, lab, conf,
                               world, t))
    return out


def _connections(bag: Path, reader, topic: str, labels_topic: str | None) -> tuple[list, list]:
    """The map topic's and the labels topic's connections, their types checked."""
    conns = [c for c in reader.connections if c.topic == topic]
    if not conns:
        raise InputError(bag, "topic", f"{topic!r} is not in the bag (topics: "
                         f"{', '.join(sorted({c.topic for c in reader.connections}))})")
    if conns[0].msgtype != "sensor_msgs/msg/PointCloud2":
        raise InputError(bag, topic, f"is {conns[0].msgtype}, not sensor_msgs/msg/PointCloud2")
    label_conns = [c for c in reader.connections if labels_topic and c.topic == labels_topic]
    if labels_topic and not label_conns:
        raise InputError(bag, "labels topic", f"{labels_topic!r} is not in the bag")
    if label_conns and label_conns[0].msgtype != "std_msgs/msg/String":
        raise InputError(bag, labels_topic, f"is {label_conns[0].msgtype}, not std_msgs/msg/String (a map's JSON "
                         "objects)")
    return conns, label_conns


def _read_messages(bag: Path, reader, store, topic: str, labels_topic, conns: list, taxonomy) -> tuple[list, list]:
    """[(stamp, map columns)] of the map topic and [(stamp, (labels, confidences))] of the
    labels topic, every message the bag's index counts read (a damaged bag is refused)."""
    maps, labels, last = [], [], -1.0
    read = dict.fromkeys((c.id for c in conns), 0)
    try:
        for conn, ns, raw in reader.messages(connections=conns):
            msg = store.deserialize_cdr(raw, conn.msgtype)
            read[conn.id] += 1
            if conn.topic != topic:
                labels.append((ns * 1e-9, _label_message(bag, labels_topic, msg.data, taxonomy)))
                continue
            t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
            if t < last:
                raise InputError(bag, f"{topic} header.stamp", f"{t:.9f} s comes after {last:.9f} s: stamps "
                                 "must not go back")
            last = t
            maps.append((t, _cloud(f"{bag} {topic} @ {t:.3f} s", msg, taxonomy)))
    except InputError:
        raise
    except Exception as err:  # the reader's or the decoder's, on bytes that are not what the index says
        raise InputError(bag, topic, f"a message cannot be read ({type(err).__name__}: {err}): the bag is "
                         "truncated or damaged") from None
    for c in conns:
        if c.msgcount and read[c.id] != c.msgcount:
            raise InputError(bag, c.topic, f"{read[c.id]} of the {c.msgcount} messages the bag's index counts "
                             "could be read: the bag is damaged")
    return maps, labels


def _cloud(where: str, msg, taxonomy) -> tuple:
    """points (P, 3), instance (P,), {id: label}, {id: confidence} of one PointCloud2."""
    from rosmeery_jax.metrics.map_score import PointColumns, read_columns  # noqa: PLC0415 (evaluate's contract)

    fields = _fields(where, msg)
    name = next((n for n in INSTANCE_FIELDS if n in fields), None)
    if name is None:
        raise InputError(where, "fields", f"no instance field ({', '.join(INSTANCE_FIELDS)}); it has "
                         f"{', '.join(fields) or 'none'}")
    rows = _rows(where, msg)
    endian = ">" if msg.is_bigendian else "<"

    def column(key: str) -> np.ndarray:
        f = fields[key]
        dtype = np.dtype(endian + _POINT_TYPES[f.datatype])
        return rows[:, f.offset:f.offset + dtype.itemsize].copy().view(dtype)[:, 0].astype(np.float64)

    xyz = np.stack([column(a) for a in "xyz"], 1).reshape(-1, 3)
    ok = ~np.isnan(xyz).any(1)  # ROS marks invalid points with NaN; infinities are refused below
    optional = {k: column(k)[ok] if k in fields else None for k in ("label", "confidence")}
    return read_columns(where, "field", PointColumns(xyz[ok], column(name)[ok], name, **optional), taxonomy)


def _fields(where: str, msg) -> dict:
    """{name: PointField}: each name once, of a PointField datatype, one value, inside a point."""
    fields = {}
    for f in msg.fields:
        if f.name in fields:
            raise InputError(where, f"field {f.name}", "appears twice: which one holds the values?")
        if f.datatype not in _POINT_TYPES:
            raise InputError(where, f"field {f.name}", f"datatype {f.datatype} is not a PointField type (1-8)")
        size = np.dtype(_POINT_TYPES[f.datatype]).itemsize
        if f.count != 1 and f.name in ("x", "y", "z", "label", "confidence", *INSTANCE_FIELDS):
            raise InputError(where, f"field {f.name}", f"count {f.count}: one value per point is read")
        if f.offset + size > msg.point_step:
            raise InputError(where, f"field {f.name}", f"offset {f.offset} + {size} bytes lies past point_step "
                             f"{msg.point_step}")
        fields[f.name] = f
    for axis in "xyz":
        if axis not in fields:
            raise InputError(where, f"field {axis}", "missing: a map needs x, y and z")
    return fields


def _rows(where: str, msg) -> np.ndarray:
    """(width x height, point_step) bytes of the cloud: its data exactly what its header
    says (width x height points of point_step bytes, rows of row_step)."""
    n, step = msg.width * msg.height, msg.point_step
    data = np.asarray(msg.data, np.uint8)
    if msg.row_step != msg.width * step:
        raise InputError(where, "row_step", f"{msg.row_step} is not width x point_step ({msg.width} x {step})")
    if len(data) != n * step:
        raise InputError(where, "data", f"{len(data)} bytes where width x height x point_step is {msg.width} x "
                         f"{msg.height} x {step} = {n * step}")
    return data.reshape(n, step) if step else np.zeros((n, 0), np.uint8)
def _label_message(bag: Path, topic: str, text: str, taxonomy) -> tuple[dict, dict]:
    """A side-channel message: {"objects": [{"id", "label", "confidence"}]}, read as a map's JSON."""
    from rosmeery_jax.metrics.map_score import object_labels  # noqa: PLC0415 (evaluate's reader)

    try:
        message = json.loads(text)
    except json.JSONDecodeError:
        message = None
    if not isinstance(message, dict):
        raise InputError(bag, f"{topic} data", "not a JSON object with an objects list")
    return object_labels(bag, message.get("objects", []), taxonomy, f"{topic} objects")
