"""Independent ROS 2 readers and writers for Revisit's bag tests.

check BAG EXPECTED.json   decode every message of a Revisit-written mcap bag with mcap-ros2-support and
                          with rosbags; each must equal the values Revisit wrote (EXPECTED: topic ->
                          {type, schema, values}).
cyclonedds OUT.json EXPECTED.json
                          decode each EXPECTED message's CDR (`cdr`, hex) with PyPI cyclonedds's IDL types
                          (for the types in IDL below); each must equal `values`. Then encode
                          `values` with them and write OUT.json: type -> list of hex CDR.
write DIR EXPECTED.json   write EXPECTED's messages with independent encoders: DIR/rosbags_db3 (sqlite3)
                          and DIR/rosbags_mcap (rosbags, with its own definitions of ROS's types), and
                          DIR/mcap_ros2.mcap (mcap-ros2-support).
listen OUT.json SPEC.json a Cyclone DDS peer on loopback in SPEC's domain: subscribe SPEC's topics
                          (topic -> {type, count, transient_local}), print "ready", and write what
                          arrives (until every count is reached, then SPEC's settle seconds) as OUT.json
                          (topic -> values) once every count is reached or SPEC's timeout passes.
talk - SPEC.json          a Cyclone DDS peer on loopback: wait for a subscriber of each of SPEC's topics
                          (topic -> {type, values}), publish the values at SPEC's rate_hz (a null value
                          skips a topic's turn), wait for acks.
"""
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.writer import Writer as McapRos2Writer
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer as RosbagsWriter
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Nodetype

REVISIT_MSGS = Path(__file__).resolve().parents[3] / "msgs" / "revisit_msgs" / "msg"


def plain(value):
    """A decoded message as JSON-like values: objects to dicts, byte strings and arrays to lists."""
    if isinstance(value, (bytes, bytearray)):
        return list(value)
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    if dataclasses.is_dataclass(value) and not hasattr(value, "__msgtype__"):  # cyclonedds
        return {f.name: plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if dataclasses.is_dataclass(value):  # rosbags: fields as its typestore defines them, not constants
        _, fields = STORE.fielddefs[value.__msgtype__]
        return {name: plain(getattr(value, name)) for name, _ in fields}
    names = getattr(value, "__slots__", None)  # mcap-ros2-support
    if names is not None:
        return {n: plain(getattr(value, n)) for n in names if n != "__msgtype__"}
    return value


def compare(where, got, want):
    if isinstance(want, dict):
        if not isinstance(got, dict) or set(got) != set(want):
            raise SystemExit(f"{where}: fields {sorted(got) if isinstance(got, dict) else got} != {sorted(want)}")
        for k in want:
            compare(f"{where}.{k}", got[k], want[k])
    elif isinstance(want, list):
        if not isinstance(got, list) or len(got) != len(want):
            raise SystemExit(f"{where}: {got!r} != {want!r}")
        for i, (g, w) in enumerate(zip(got, want)):
            compare(f"{where}[{i}]", g, w)
    else:
        if isinstance(got, bytes) and len(got) == 1:  # a ROS `byte` scalar
            got = got[0]
        if got != want or isinstance(got, bool) != isinstance(want, bool):
            raise SystemExit(f"{where}: {got!r} != {want!r}")


def typestore():
    store = get_typestore(Stores.ROS2_HUMBLE)
    for path in sorted(REVISIT_MSGS.glob("*.msg")):
        store.register(get_types_from_msg(path.read_text(), f"revisit_msgs/msg/{path.stem}"))
    return store


STORE = typestore()


def check(bag, expected):
    bag = Path(bag)
    decoded = {}
    with open(next(bag.glob("*.mcap")), "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2", reader.get_header()
        for _, channel, _, message in reader.iter_decoded_messages(log_time_order=False):
            decoded.setdefault(channel.topic, []).append(plain(message))
    by_rosbags = {}
    with AnyReader([bag], default_typestore=STORE) as reader:
        for connection, _, raw in reader.messages():
            by_rosbags.setdefault(connection.topic, []).append(plain(reader.deserialize(raw, connection.msgtype)))
    for name, got in (("mcap-ros2-support", decoded), ("rosbags", by_rosbags)):
        if set(got) != set(expected):
            raise SystemExit(f"{name}: topics {sorted(set(got) ^ set(expected))} differ")
        for topic, entry in expected.items():
            compare(f"{name} {topic}", got[topic], entry["values"])
    count = sum(len(e["values"]) for e in expected.values())
    print(f"check: {count} messages of {len(expected)} types equal in mcap-ros2-support and rosbags")


NUMPY = {"bool": np.bool_, "byte": np.uint8, "char": np.uint8, "int8": np.int8, "uint8": np.uint8,
         "int16": np.int16, "uint16": np.uint16, "int32": np.int32, "uint32": np.uint32,
         "int64": np.int64, "uint64": np.uint64, "float32": np.float32, "float64": np.float64}


def build(store, typename, value):
    """A rosbags message object of `typename` from JSON-like values."""
    _, fields = store.fielddefs[typename]
    return store.types[typename](**{name: build_field(store, desc, value[name]) for name, desc in fields})


def build_field(store, desc, value):
    kind, detail = desc
    if kind == Nodetype.NAME:
        return build(store, detail, value)
    if kind == Nodetype.BASE:
        return value
    (sub_kind, sub_detail), _ = detail
    if sub_kind == Nodetype.BASE and sub_detail[0] in NUMPY:
        return np.array(value, dtype=NUMPY[sub_detail[0]])
    return [build_field(store, (sub_kind, sub_detail), v) for v in value]


def write(out, expected):
    out = Path(out)
    store = STORE
    for storage, name in ((StoragePlugin.SQLITE3, "rosbags_db3"), (StoragePlugin.MCAP, "rosbags_mcap")):
        with RosbagsWriter(out / name, version=8, storage_plugin=storage) as writer:
            for topic, entry in expected.items():
                connection = writer.add_connection(topic, entry["type"], typestore=store)
                for i, value in enumerate(entry["values"]):
                    message = build(store, entry["type"], value)
                    writer.write(connection, 1_000_000_000 + i, store.serialize_cdr(message, entry["type"]))
    with open(out / "mcap_ros2.mcap", "wb") as f:
        writer = McapRos2Writer(f)
        for topic, entry in expected.items():
            schema = writer.register_msgdef(entry["type"], entry["schema"])
            for i, value in enumerate(entry["values"]):
                writer.write_message(topic, schema, value, log_time=1_000_000_000 + i, publish_time=1_000_000_000 + i)
        writer.finish()
    print(f"write: {out}")


def idl_types():
    """A few ROS 2 types as Cyclone DDS IDL, written from the ROS definitions independently of Revisit."""
    from dataclasses import dataclass

    from cyclonedds.idl import IdlStruct
    from cyclonedds.idl.types import array, float64, int8, int32, sequence, uint8, uint16, uint32

    @dataclass
    class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
        sec: int32
        nanosec: uint32

    @dataclass
    class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
        stamp: Time
        frame_id: str

    @dataclass
    class Image(IdlStruct, typename="sensor_msgs::msg::dds_::Image_"):
        header: Header
        height: uint32
        width: uint32
        encoding: str
        is_bigendian: uint8
        step: uint32
        data: sequence[uint8]

    @dataclass
    class RegionOfInterest(IdlStruct, typename="sensor_msgs::msg::dds_::RegionOfInterest_"):
        x_offset: uint32
        y_offset: uint32
        height: uint32
        width: uint32
        do_rectify: bool

    @dataclass
    class CameraInfo(IdlStruct, typename="sensor_msgs::msg::dds_::CameraInfo_"):
        header: Header
        height: uint32
        width: uint32
        distortion_model: str
        d: sequence[float64]
        k: array[float64, 9]
        r: array[float64, 9]
        p: array[float64, 12]
        binning_x: uint32
        binning_y: uint32
        roi: RegionOfInterest

    @dataclass
    class NavSatStatus(IdlStruct, typename="sensor_msgs::msg::dds_::NavSatStatus_"):
        status: int8
        service: uint16

    @dataclass
    class NavSatFix(IdlStruct, typename="sensor_msgs::msg::dds_::NavSatFix_"):
        header: Header
        status: NavSatStatus
        latitude: float64
        longitude: float64
        altitude: float64
        position_covariance: array[float64, 9]
        position_covariance_type: uint8

    @dataclass
    class Point(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
        x: float64
        y: float64
        z: float64

    @dataclass
    class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
        x: float64
        y: float64
        z: float64
        w: float64

    @dataclass
    class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
        position: Point
        orientation: Quaternion

    @dataclass
    class PoseWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovariance_"):
        pose: Pose
        covariance: array[float64, 36]

    @dataclass
    class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
        x: float64
        y: float64
        z: float64

    @dataclass
    class Twist(IdlStruct, typename="geometry_msgs::msg::dds_::Twist_"):
        linear: Vector3
        angular: Vector3

    @dataclass
    class TwistWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::TwistWithCovariance_"):
        twist: Twist
        covariance: array[float64, 36]

    @dataclass
    class Odometry(IdlStruct, typename="nav_msgs::msg::dds_::Odometry_"):
        header: Header
        child_frame_id: str
        pose: PoseWithCovariance
        twist: TwistWithCovariance

    @dataclass
    class PoseStamped(IdlStruct, typename="geometry_msgs::msg::dds_::PoseStamped_"):
        header: Header
        pose: Pose

    @dataclass
    class Path(IdlStruct, typename="nav_msgs::msg::dds_::Path_"):
        header: Header
        poses: sequence[PoseStamped]

    @dataclass
    class PointField(IdlStruct, typename="sensor_msgs::msg::dds_::PointField_"):
        name: str
        offset: uint32
        datatype: uint8
        count: uint32

    @dataclass
    class PointCloud2(IdlStruct, typename="sensor_msgs::msg::dds_::PointCloud2_"):
        header: Header
        height: uint32
        width: uint32
        fields: sequence[PointField]
        is_bigendian: bool
        point_step: uint32
        row_step: uint32
        data: sequence[uint8]
        is_dense: bool

    @dataclass
    class SessionStatus(IdlStruct, typename="revisit_msgs::msg::dds_::SessionStatus_"):
        session: str
        visit: uint32
        images: uint32
        registered: uint32

    @dataclass
    class MapStatus(IdlStruct, typename="revisit_msgs::msg::dds_::MapStatus_"):
        header: Header
        state: uint8
        message: str
        sessions: sequence[SessionStatus]
        points: uint32
        mean_reprojection_error_px: float64

    @dataclass
    class Transform(IdlStruct, typename="geometry_msgs::msg::dds_::Transform_"):
        translation: Vector3
        rotation: Quaternion

    @dataclass
    class TransformStamped(IdlStruct, typename="geometry_msgs::msg::dds_::TransformStamped_"):
        header: Header
        child_frame_id: str
        transform: Transform

    @dataclass
    class TFMessage(IdlStruct, typename="tf2_msgs::msg::dds_::TFMessage_"):
        transforms: sequence[TransformStamped]

    @dataclass
    class SessionControl(IdlStruct, typename="revisit_msgs::msg::dds_::SessionControl_"):
        header: Header
        command: uint8
        session: str
        source: str
        keyframes: uint32

    return {"builtin_interfaces/msg/Time": Time, "std_msgs/msg/Header": Header, "sensor_msgs/msg/Image": Image,
            "sensor_msgs/msg/CameraInfo": CameraInfo, "sensor_msgs/msg/NavSatFix": NavSatFix,
            "nav_msgs/msg/Odometry": Odometry, "nav_msgs/msg/Path": Path,
            "sensor_msgs/msg/PointCloud2": PointCloud2, "revisit_msgs/msg/MapStatus": MapStatus,
            "revisit_msgs/msg/SessionControl": SessionControl, "tf2_msgs/msg/TFMessage": TFMessage}


def idl_value(cls, value):
    """An IDL struct from JSON-like values."""
    import typing

    from cyclonedds.idl import IdlStruct
    hints = typing.get_type_hints(cls)
    fields = {}
    for f in dataclasses.fields(cls):
        hint = hints[f.name]
        if isinstance(hint, type) and issubclass(hint, IdlStruct):
            fields[f.name] = idl_value(hint, value[f.name])
        else:
            fields[f.name] = value[f.name]
    return cls(**fields)


def cyclonedds(out, expected):
    types = idl_types()
    encoded = {}
    for name, entry in expected.items():
        cls = types[name]
        for i, (value, cdr) in enumerate(zip(entry["values"], entry["cdr"])):
            compare(f"cyclonedds {name}[{i}]", plain(cls.deserialize(bytes.fromhex(cdr))), value)
        encoded[name] = [idl_value(cls, value).serialize().hex() for value in entry["values"]]
    Path(out).write_text(json.dumps(encoded))
    print(f"cyclonedds: {len(expected)} types equal both ways")


def dds_participant(spec):
    """A Cyclone DDS participant that stays on loopback and finds peers there by unicast."""
    import os
    os.environ["CYCLONEDDS_URI"] = (
        "<CycloneDDS><Domain id='any'><General><Interfaces><NetworkInterface address='127.0.0.1'/>"
        "</Interfaces><AllowMulticast>false</AllowMulticast></General><Discovery>"
        "<ParticipantIndex>auto</ParticipantIndex><MaxAutoParticipantIndex>60</MaxAutoParticipantIndex>"
        "<Peers><Peer address='127.0.0.1'/></Peers></Discovery></Domain></CycloneDDS>")
    from cyclonedds.domain import DomainParticipant
    return DomainParticipant(spec["domain"])


def reliable_qos(depth=1000, transient_local=False):
    from cyclonedds.qos import Policy, Qos
    from cyclonedds.util import duration
    durability = Policy.Durability.TransientLocal if transient_local else Policy.Durability.Volatile
    return Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.History.KeepLast(depth), durability)


def endpoints(spec, kind, types):
    """A reliable DataReader or DataWriter (`kind`) per topic of SPEC, in SPEC's domain; transient
    local where the topic's entry says `"transient_local": true` (a late reader of latched topics)."""
    from cyclonedds.topic import Topic
    participant = dds_participant(spec)
    return {name: kind(participant, Topic(participant, "rt" + name, types[entry["type"]]),
                       qos=reliable_qos(transient_local=entry.get("transient_local", False)))
            for name, entry in spec["topics"].items()}


def listen(out, spec):
    import time

    from cyclonedds.sub import DataReader
    readers = endpoints(spec, DataReader, idl_types())
    print("ready", flush=True)
    got = {name: [] for name in readers}

    def take():
        # Only samples with data: when a writer leaves, its instances' state change comes as a
        # sample without data (valid_data false), as in any DDS reader.
        for name, reader in readers.items():
            got[name].extend(plain(sample) for sample in reader.take(N=100) if sample.sample_info.valid_data)

    deadline = time.monotonic() + spec.get("timeout", 60)
    while time.monotonic() < deadline and any(len(got[n]) < e["count"] for n, e in spec["topics"].items()):
        take()
        time.sleep(0.005)
    settle = time.monotonic() + spec.get("settle", 0)  # whatever else is on its way
    while time.monotonic() < settle:
        take()
        time.sleep(0.005)
    Path(out).write_text(json.dumps(got))
    print("listen: " + ", ".join(f"{name} {len(values)}" for name, values in got.items()), flush=True)


def talk(_, spec):
    import time

    from cyclonedds.pub import DataWriter
    types = idl_types()
    writers = endpoints(spec, DataWriter, types)
    deadline = time.monotonic() + spec.get("timeout", 60)
    while any(not w.get_matched_subscriptions() for w in writers.values()):
        if time.monotonic() > deadline:
            raise SystemExit("talk: no subscriber appeared")
        time.sleep(0.05)
    time.sleep(1.0)  # the subscriber's side of the match
    count = max(len(e["values"]) for e in spec["topics"].values())
    for i in range(count):
        for name, entry in spec["topics"].items():
            if i < len(entry["values"]) and entry["values"][i] is not None:
                writers[name].write(idl_value(types[entry["type"]], entry["values"][i]))
        time.sleep(1.0 / spec.get("rate_hz", 10))
    time.sleep(2.0)  # reliable repairs (cyclonedds's wait_for_acks fails on its timeout path)
    print(f"talk: {count} messages on each of {len(writers)} topics", flush=True)


if __name__ == "__main__":
    command, path, spec_path = sys.argv[1:]
    spec = json.loads(Path(spec_path).read_text())
    {"check": check, "write": write, "cyclonedds": cyclonedds, "listen": listen, "talk": talk}[command](path, spec)
