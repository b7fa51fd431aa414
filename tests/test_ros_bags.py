"""ROS 2 bags: a recording written as a bag and read back with rosbags' own reader (types,
frames, stamps, encodings, intrinsics, depth that lands on the objects), and maps a ROS
mapper would publish, written by rosbags' writer here, scored as the same map in PLY."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

pytest.importorskip("rosbags")
from rosbags.rosbag2 import Reader, StoragePlugin, Writer  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

from rosmeery_jax.apps.cli import main  # noqa: E402
from rosmeery_jax.apps.ros_bags import typestore  # noqa: E402
from rosmeery_jax.metrics.map_score import read_map  # noqa: E402
from rosmeery_jax.world import load_world  # noqa: E402

ARGS = ["record", "--world", "small_office", "--policy", "frontier", "--duration", "4", "--width", "160",
        "--height", "120", "--rate", "5", "--seed", "0", "--quiet"]
STORE = get_typestore(Stores.ROS2_HUMBLE)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """The same run as a TUM folder and as an MCAP bag with the oracle detector's boxes."""
    root = tmp_path_factory.mktemp("bags")
    assert main([*ARGS, "--out", str(root / "tum")]) == 0
    assert main([*ARGS, "--format", "mcap", "--detector", "oracle", "--out", str(root / "mcap")]) == 0
    return root


def _messages(bag: Path) -> dict:
    store = typestore()
    out: dict = {}
    with Reader(bag) as reader:
        for conn, ns, raw in reader.messages():
            out.setdefault(conn.topic, []).append((ns, conn.msgtype, store.deserialize_cdr(raw, conn.msgtype)))
    return out


def _matrix(tf) -> np.ndarray:
    t, q = tf.transform.translation, tf.transform.rotation
    m = np.eye(4)
    m[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    m[:3, 3] = [t.x, t.y, t.z]
    return m


def test_the_bag_has_the_standard_topics_frames_and_encodings(recorded):
    msgs = _messages(recorded / "mcap" / "seed0" / "bag")
    types = {topic: m[0][1] for topic, m in msgs.items()}
    assert types == {"/clock": "rosgraph_msgs/msg/Clock", "/tf": "tf2_msgs/msg/TFMessage",
                     "/tf_static": "tf2_msgs/msg/TFMessage", "/odom": "nav_msgs/msg/Odometry",
                     "/ground_truth/odom": "nav_msgs/msg/Odometry", "/scan": "sensor_msgs/msg/LaserScan",
                     "/camera/color/image_raw": "sensor_msgs/msg/Image",
                     "/camera/color/camera_info": "sensor_msgs/msg/CameraInfo",
                     "/camera/depth/image_raw": "sensor_msgs/msg/Image",
                     "/camera/depth/camera_info": "sensor_msgs/msg/CameraInfo",
                     "/detections": "vision_msgs/msg/Detection2DArray"}
    assert len(msgs["/scan"]) == 41 and len(msgs["/camera/color/image_raw"]) == 21  # 10 Hz and 5 Hz over 4 s
    for topic, m in msgs.items():  # stamps in order, and each message's header stamp its log time
        ns = [x[0] for x in m]
        assert ns == sorted(ns), topic
    rgb, depth = msgs["/camera/color/image_raw"][5][2], msgs["/camera/depth/image_raw"][5][2]
    assert (rgb.encoding, rgb.width, rgb.height, rgb.step) == ("rgb8", 160, 120, 480)
    assert (depth.encoding, depth.step, depth.header.frame_id) == ("32FC1", 640, "camera_optical_frame")
    assert msgs["/odom"][0][2].header.frame_id == "odom" and msgs["/odom"][0][2].child_frame_id == "base_link"
    assert msgs["/ground_truth/odom"][0][2].header.frame_id == "map"
    assert msgs["/scan"][3][2].header.frame_id == "laser" and len(msgs["/scan"][3][2].ranges) == 90
    tf = msgs["/tf"][0][2].transforms
    assert [(t.header.frame_id, t.child_frame_id) for t in tf] == [("map", "odom"), ("odom", "base_link")]
    static = msgs["/tf_static"][0][2].transforms
    assert [(t.header.frame_id, t.child_frame_id) for t in static] == [
        ("base_link", "camera_link"), ("camera_link", "camera_optical_frame"), ("base_link", "laser")]
    info = msgs["/camera/color/camera_info"][0][2]
    cam = json.loads((recorded / "mcap" / "seed0" / "camera.json").read_text())
    np.testing.assert_allclose(info.k.reshape(3, 3), [[cam["fx"], 0, cam["cx"]], [0, cam["fy"], cam["cy"]],
                                                      [0, 0, 1]])
    dets = [d for _, _, m in msgs["/detections"] for d in m.detections]
    assert dets and all(d.results[0].hypothesis.class_id in load_world("small_office").taxonomy for d in dets)


def test_depth_back_projected_with_camera_info_and_tf_lands_on_the_objects(recorded, tmp_path):
    """The bag's depth, back-projected with its CameraInfo and its transforms map -> odom ->
    base_link -> camera_link -> camera_optical_frame, equals the TUM recording's depth and
    camera poses, and its object pixels (the TUM folder's instance images) lie on objects."""
    msgs = _messages(recorded / "mcap" / "seed0" / "bag")
    tum = recorded / "tum" / "seed0"
    static = {t.child_frame_id: _matrix(t) for t in msgs["/tf_static"][0][2].transforms}
    tf_at = {ns: [_matrix(t) for t in m.transforms] for ns, _, m in msgs["/tf"]}
    gt = {f"{float(r[0]):.6f}": np.array(r[1:], float) for r in
          (line.split() for line in (tum / "groundtruth.txt").read_text().splitlines() if not line.startswith("#"))}
    info = msgs["/camera/depth/camera_info"][0][2]
    k = info.k.reshape(3, 3)
    points, ids = [], []
    for ns, _, img in msgs["/camera/depth/image_raw"]:
        stamp = f"{ns * 1e-9:.6f}"
        depth = np.frombuffer(img.data.tobytes(), "<f4").reshape(img.height, img.width)
        tum_depth = cv2.imread(str(tum / "depth" / f"{stamp}.png"), cv2.IMREAD_UNCHANGED) / 5000.0
        np.testing.assert_allclose(np.nan_to_num(depth), tum_depth, atol=1e-4)  # TUM: 0.2 mm steps
        map_odom, odom_base = tf_at[ns]
        pose = map_odom @ odom_base @ static["camera_link"] @ static["camera_optical_frame"]
        t, q = gt[stamp][:3], gt[stamp][3:]
        np.testing.assert_allclose(pose[:3, 3], t, atol=1e-5)
        np.testing.assert_allclose(np.abs(Rotation.from_matrix(pose[:3, :3]).as_quat() @ q), 1.0, atol=1e-5)
        seg = cv2.imread(str(tum / "seg" / f"{stamp}.png"), cv2.IMREAD_UNCHANGED).astype(int) - 1
        v, u = np.nonzero((seg >= 0) & np.isfinite(depth))
        z = depth[v, u]
        cam = np.stack([(u - k[0, 2]) * z / k[0, 0], (v - k[1, 2]) * z / k[1, 1], z, np.ones_like(z)])
        points.append((pose @ cam)[:3].T)
        ids.append(seg[v, u])
    points, ids = np.concatenate(points), np.concatenate(ids)
    assert len(points) > 1000
    _write_ply(tmp_path / "map.ply", points, ids)
    (tmp_path / "map.json").write_text(json.dumps({"frame": {"world": "small_office", "time_s": 4.0}}))
    assert main(["evaluate", "--world", "small_office", "--map", str(tmp_path / "map.ply"),
                 "--out", str(tmp_path / "ev")]) == 0
    summary = json.loads((tmp_path / "ev" / "summary.json").read_text())
    assert summary["points_on_no_object"] < 0.005 and summary["ori"] > 0.05


def _write_ply(path: Path, points: np.ndarray, ids: np.ndarray) -> None:
    rows = np.zeros(len(points), dtype=[("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("object_id", "<i4")])
    rows["x"], rows["y"], rows["z"], rows["object_id"] = *points.T, ids
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(points)}\nproperty double x\n"
              "property double y\nproperty double z\nproperty int object_id\nend_header\n")
    path.write_bytes(header.encode() + rows.tobytes())


def _cloud(points, instance, stamp_s: float, fields=("x", "y", "z", "instance")):
    """A PointCloud2 built by hand: float64 x, y, z and int32 instance (as a ROS mapper would)."""
    T = STORE.types
    kinds = {"x": (8, "<f8"), "y": (8, "<f8"), "z": (8, "<f8"), "instance": (5, "<i4"), "segment": (5, "<i4")}
    dtype = np.dtype([(f, kinds[f][1]) for f in fields])
    rows = np.zeros(len(points), dtype)
    for axis, col in zip("xyz", points.T):
        rows[axis] = col
    rows[fields[3]] = instance
    offsets = [dtype.fields[f][1] for f in fields]
    sec = int(stamp_s)
    return T["sensor_msgs/msg/PointCloud2"](
        header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](
            sec=sec, nanosec=int(round((stamp_s - sec) * 1e9))), frame_id="map"),
        height=1, width=len(points), fields=[T["sensor_msgs/msg/PointField"](
            name=f, offset=o, datatype=kinds[f][0], count=1) for f, o in zip(fields, offsets)],
        is_bigendian=False, point_step=dtype.itemsize, row_step=dtype.itemsize * len(points),
        data=np.frombuffer(rows.tobytes(), np.uint8), is_dense=True)


def _map_bag(path: Path, clouds: list, labels: dict | None = None) -> None:
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        c = w.add_connection("/semantic_map", "sensor_msgs/msg/PointCloud2", typestore=STORE)
        s = w.add_connection("/semantic_map/labels", "std_msgs/msg/String", typestore=STORE) if labels else None
        if labels:
            w.write(s, 0, STORE.serialize_cdr(STORE.types["std_msgs/msg/String"](data=json.dumps(labels)),
                                              "std_msgs/msg/String"))
        for t, msg in clouds:
            w.write(c, int(t * 1e9), STORE.serialize_cdr(msg, "sensor_msgs/msg/PointCloud2"))


def test_a_map_topic_written_by_another_tool_scores_as_the_same_map_in_ply(recorded, tmp_path):
    ply = recorded / "mcap" / "session" / "maps" / "small_office__frontier__seed0.ply"
    world = load_world("small_office")
    m = read_map(ply, world.taxonomy)
    meta = json.loads(ply.with_suffix(".json").read_text())
    labels = {"objects": [{"id": o["id"], "label": o["label"], "confidence": o["confidence"]}
                          for o in meta["objects"]]}
    half = len(m.points) // 2
    bag = tmp_path / "maps"
    _map_bag(bag, [(2.0, _cloud(m.points[:half], m.instance[:half], 2.0)),
                   (m.time_s, _cloud(m.points, m.instance, m.time_s))], labels)
    assert main(["evaluate", "--world", "small_office", "--bag", str(bag), "--labels-topic", "/semantic_map/labels",
                 "--metrics", "ori,cori,opi,field", "--out", str(tmp_path / "from_bag")]) == 0
    assert main(["evaluate", "--world", "small_office", "--map", str(ply), "--metrics", "ori,cori,opi,field",
                 "--out", str(tmp_path / "from_ply")]) == 0
    a = json.loads((tmp_path / "from_bag" / "summary.json").read_text())
    b = json.loads((tmp_path / "from_ply" / "summary.json").read_text())
    for key in ("ori", "cori", "opi", "omq", "ap50", "f1_25", "completeness_5cm", "miou", "points_on_no_object"):
        assert a[key] == pytest.approx(b[key], abs=1e-6), key  # ORI in float32, from 2 maps or 1
    assert len(a["maps"]) == 2 and a["ori"] > 0


@pytest.mark.parametrize("case, field", [("no topic", "topic"), ("no instance field", "fields"),
                                         ("stamps go back", "header.stamp"), ("truncated", "bag")])
def test_a_bad_bag_is_one_line_naming_file_topic_and_field(tmp_path, capsys, case, field):
    pts = np.array([[0.0, 0.0, 0.5], [0.1, 0.0, 0.5]])
    bag = tmp_path / "bag"
    if case == "no instance field":
        _map_bag(bag, [(1.0, _cloud(pts, [0, 0], 1.0, ("x", "y", "z", "segment")))])
    elif case == "stamps go back":
        _map_bag(bag, [(1.0, _cloud(pts, [0, 0], 2.0)), (2.0, _cloud(pts, [0, 0], 1.0))])
    else:
        _map_bag(bag, [(1.0, _cloud(pts, [0, 0], 1.0))])
    if case == "truncated":
        mcap = next(bag.glob("*.mcap"))
        mcap.write_bytes(mcap.read_bytes()[:200])
    topic = "/elsewhere" if case == "no topic" else "/semantic_map"
    out = tmp_path / "out"
    assert main(["evaluate", "--world", "small_office", "--bag", str(bag), "--topic", topic, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(bag) in err[0] and field in err[0], err
    assert not out.exists()


def test_a_sqlite3_bag_holds_the_same_messages(tmp_path):
    """The writer's two storage formats: a few steps and a frame as SQLite 3, read back."""
    from rosmeery_jax.apps.ros_bags import BagStreams
    from rosmeery_jax.raycast.sensors import CameraConfig, LaserConfig, laser_dirs

    bag = tmp_path / "bag"
    streams = BagStreams(bag, "sqlite3", depth_encoding="16UC1")
    streams.static(CameraConfig(), LaserConfig())
    for k in range(3):
        streams.step(0.1 * k, np.array([0.1 * k, 0.0, 0.0]), np.array([0.1 * k, 0.0, 0.0]), 1.0, 0.0,
                     np.full(90, 2.0), LaserConfig(), laser_dirs(LaserConfig()))
    intr = {"width": 4, "height": 3, "fx": 2.0, "fy": 2.0, "cx": 1.5, "cy": 1.0}
    streams.frame(0.2, np.zeros((3, 4, 3), np.uint8), np.full((3, 4), 1.234, np.float32), intr)
    streams.close()
    assert next(bag.glob("*.db3"))
    msgs = _messages(bag)
    assert len(msgs["/odom"]) == 3 and "/detections" not in msgs
    depth = msgs["/camera/depth/image_raw"][0][2]
    assert depth.encoding == "16UC1" and np.frombuffer(depth.data.tobytes(), "<u2").tolist() == [1234] * 12


def test_the_tf_chain_map_odom_base_is_the_true_pose_at_every_stamp_with_drift(tmp_path):
    """Odometry that drifts in position and heading (as dead reckoning does): at every stamp
    map -> odom composed with odom -> base_link is the true pose (/ground_truth/odom), and
    odom -> base_link is the odometry (/odom)."""
    from rosmeery_jax.apps.ros_bags import BagStreams
    from rosmeery_jax.raycast.sensors import CameraConfig, LaserConfig, laser_dirs

    rng = np.random.default_rng(3)
    t = np.arange(60) * 0.1
    true = np.stack([2.0 + np.cos(t), 1.0 + np.sin(2 * t), np.angle(np.exp(1j * (0.5 + 1.3 * t)))], 1)
    drift = np.cumsum(rng.normal(0, [0.02, 0.02, 0.03], (60, 3)), 0)  # up to tens of cm and degrees
    odom = true + drift
    bag = tmp_path / "bag"
    streams = BagStreams(bag, "mcap")
    streams.static(CameraConfig(), LaserConfig())
    for k in range(60):
        streams.step(t[k], odom[k], true[k], 0.5, 0.1, np.full(90, 2.0), LaserConfig(), laser_dirs(LaserConfig()))
    streams.close()
    msgs = _messages(bag)
    assert len(msgs["/tf"]) == 60 and np.abs(drift[:, :2]).max() > 0.1
    for k, ((_, _, tf), (_, _, gt), (_, _, od)) in enumerate(zip(msgs["/tf"], msgs["/ground_truth/odom"],
                                                                  msgs["/odom"])):
        map_odom, odom_base = (_matrix(x) for x in tf.transforms)
        chain = map_odom @ odom_base
        yaw = np.arctan2(chain[1, 0], chain[0, 0])
        np.testing.assert_allclose(chain[:2, 3], true[k, :2], atol=1e-9)
        assert abs(np.angle(np.exp(1j * (yaw - true[k, 2])))) < 1e-9
        p, q = gt.pose.pose.position, gt.pose.pose.orientation
        np.testing.assert_allclose([p.x, p.y], chain[:2, 3], atol=1e-9)
        np.testing.assert_allclose(odom_base[:2, 3], odom[k, :2], atol=1e-9)
        assert od.pose.pose.position.x == pytest.approx(odom[k, 0])
        gt_yaw = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_euler("zyx")[0]
        assert abs(np.angle(np.exp(1j * (gt_yaw - yaw)))) < 1e-9


_KINDS = {"f8": 8, "f4": 7, "i4": 5, "u1": 2}


def _raw_cloud(rows: np.ndarray, stamp_s: float = 1.0, **header):
    """A PointCloud2 of the structured array ``rows`` (its field names and types), with any
    header field (width, point_step, fields, is_bigendian, ...) overridden by ``header``."""
    T = STORE.types
    fields = [T["sensor_msgs/msg/PointField"](name=n, offset=rows.dtype.fields[n][1],
                                              datatype=_KINDS[rows.dtype.fields[n][0].str[1:]], count=1)
              for n in rows.dtype.names]
    sec = int(stamp_s)
    values = dict(height=1, width=len(rows), fields=fields, is_bigendian=False, point_step=rows.dtype.itemsize,
                  row_step=rows.dtype.itemsize * len(rows), data=np.frombuffer(rows.tobytes(), np.uint8),
                  is_dense=False)
    values.update(header)
    return T["sensor_msgs/msg/PointCloud2"](header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](
        sec=sec, nanosec=int(round((stamp_s - sec) * 1e9))), frame_id="map"), **values)


def _rows(n: int = 50, **columns) -> np.ndarray:
    """n points on the Small Office's first object's samples, instance 0, label and
    confidence columns as given (name: (dtype, values))."""
    pts = np.asarray(load_world("small_office").truth.samples.points, np.float64)[:n]
    dtype = [("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("instance", "<i4")]
    dtype += [(k, v[0]) for k, v in columns.items()]
    rows = np.zeros(n, dtype)
    rows["x"], rows["y"], rows["z"] = pts.T
    for k, (_, values) in columns.items():
        rows[k] = values
    return rows


def _damaged(bag: Path) -> None:
    """The first of the bag's two clouds no longer a Message record (its opcode zeroed), as a
    flipped byte leaves it: rosbags' reader then skips it without a word."""
    mcap = next(bag.glob("*.mcap"))
    data = bytearray(mcap.read_bytes())
    payload = STORE.serialize_cdr(_raw_cloud(_rows()), "sensor_msgs/msg/PointCloud2")
    start = data.find(bytes(payload)) - 31  # MCAP Message: opcode, length, channel, sequence, two times
    assert start > 0 and data[start] == 0x05
    data[start] = 0
    mcap.write_bytes(bytes(data))


SIX_X = np.zeros(50, [("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("x2", "<f8"), ("instance", "<i4")])


@pytest.mark.parametrize("case, field", [
    ("confidence 5", "field confidence"), ("confidence -1", "field confidence"),
    ("confidence NaN", "field confidence"), ("big-endian flag over little-endian data", "field"),
    ("label 99", "field label"), ("label -5", "field label"), ("label NaN", "field label"),
    ("instance 3e9", "field instance"), ("x twice", "field x"), ("width 100 of 14479 points", "data"),
    ("offset past point_step", "field z"), ("labels topic of another type", "/semantic_map/labels"),
    ("damaged", "damaged"), ("infinite x", "field x, y, z"),
])
def test_a_cloud_is_held_to_the_reader_contract_of_a_ply_map(tmp_path, capsys, case, field):
    """What a PLY map refuses, a bag refuses: one line naming the bag, the topic, the cloud's
    stamp and the field; nothing written."""
    bag = tmp_path / "bag"
    rows = _rows(confidence=("<f8", 0.9), label=("<f8", 3.0))
    if case.startswith("confidence"):
        rows["confidence"][7] = {"5": 5.0, "-1": -1.0, "NaN": np.nan}[case.split()[1]]
    if case.startswith("label "):
        rows["label"][7] = {"99": 99.0, "-5": -5.0, "NaN": np.nan}[case.split()[1]]
    if case == "infinite x":
        rows["x"][7] = np.inf
    header = {}
    if case == "big-endian flag over little-endian data":
        header["is_bigendian"] = True
    if case == "instance 3e9":
        rows = _rows(instance64=("<f8", 3e9))
        rows = rows[["x", "y", "z", "instance64"]]
        rows.dtype.names = ("x", "y", "z", "instance")
        rows = np.ascontiguousarray(rows)
    if case == "x twice":
        msg = _raw_cloud(SIX_X)
        msg.fields[3].name = "x"
    elif case == "width 100 of 14479 points":
        msg = _raw_cloud(np.resize(rows, 14479), width=100, row_step=100 * rows.dtype.itemsize)
    elif case == "offset past point_step":
        msg = _raw_cloud(rows)
        msg.fields[2].offset = rows.dtype.itemsize - 4
    else:
        msg = _raw_cloud(rows, **header)
    clouds = [(1.0, msg)]
    if case == "damaged":
        clouds = [(1.0, _raw_cloud(_rows())), (2.0, _raw_cloud(_rows(), 2.0))]
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        c = w.add_connection("/semantic_map", "sensor_msgs/msg/PointCloud2", typestore=STORE)
        if case == "labels topic of another type":
            s = w.add_connection("/semantic_map/labels", "std_msgs/msg/Int32", typestore=STORE)
            w.write(s, 0, STORE.serialize_cdr(STORE.types["std_msgs/msg/Int32"](data=3), "std_msgs/msg/Int32"))
        for t, m in clouds:
            w.write(c, int(t * 1e9), STORE.serialize_cdr(m, "sensor_msgs/msg/PointCloud2"))
    if case == "damaged":
        _damaged(bag)
    out = tmp_path / "out"
    labels = ["--labels-topic", "/semantic_map/labels"] if "labels topic" in case else []
    assert main(["evaluate", "--world", "small_office", "--bag", str(bag), *labels, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(bag) in err[0] and field in err[0], err
    assert "/semantic_map" in err[0] and "truncat" not in err[0]
    if case not in ("damaged", "labels topic of another type"):
        assert "@ 1.000 s" in err[0], err
    assert not out.exists()


def test_an_empty_or_all_nan_cloud_is_an_empty_map_scored_zero(tmp_path):
    """A mapper's first map is often empty: it scores 0 (no NaN), beside a later real one."""
    empty = _rows(0)
    nan = _rows(20)
    nan["x"] = np.nan
    full = _rows(200)
    bag = tmp_path / "bag"
    _map_bag(bag, [(1.0, _raw_cloud(empty, 1.0)), (2.0, _raw_cloud(nan, 2.0)), (3.0, _raw_cloud(full, 3.0))])
    assert main(["evaluate", "--world", "small_office", "--bag", str(bag), "--metrics", "ori,cori,opi,field",
                 "--out", str(tmp_path / "o")]) == 0
    import pandas as pd
    m = pd.read_csv(tmp_path / "o" / "metrics.csv")
    assert not m.value.isna().any()
    ori = m[m.metric == "ori"].sort_values("time_s").value.tolist()
    assert ori[:2] == [0.0, 0.0] and ori[2] > 0
