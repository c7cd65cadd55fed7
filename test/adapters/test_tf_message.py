"""tf2_msgs/TFMessage as this machine has it: upstream's type hash and wire format.

No wheel carries tf2_msgs; ``vendor/tf2_msgs`` defines it for ``make setup``. A definition that
differed from upstream's would have another type hash (Jazzy's DDS type matching would keep a
real cell's ``/tf`` from ever arriving) or another wire layout.
"""

import json
from pathlib import Path

import numpy as np
import tf2_msgs
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.typesys import get_typestore, Stores
from scipy.spatial.transform import Rotation
from tf2_msgs.msg import TFMessage

from msg_adapters.geometry import stamp_to_sec, transform_to_msg

NAME = 'tf2_msgs/msg/TFMessage'


def test_type_hash_is_upstreams():
    # the description beside the module imported: <prefix>/lib/pythonX.Y/site-packages/tf2_msgs
    prefix = Path(tf2_msgs.__file__).resolve().parents[4]
    described = json.loads((prefix / 'share' / 'tf2_msgs' / 'msg' / 'TFMessage.json')
                           .read_text())
    ours = {h['type_name']: h['hash_string'] for h in described['type_hashes']}
    store = get_typestore(Stores.ROS2_JAZZY)  # upstream's definitions, hashed independently
    assert ours[NAME] == store.hash_rihs01(NAME)
    assert ours['geometry_msgs/msg/TransformStamped'] == store.hash_rihs01(
        'geometry_msgs/msg/TransformStamped')


def test_wire_format_reads_back_with_upstreams_definition():
    rng = np.random.default_rng(2)
    matrices = []
    for _ in range(3):
        m = np.eye(4)
        m[:3, :3] = Rotation.random(random_state=rng).as_matrix()
        m[:3, 3] = rng.uniform(-1, 1, 3)
        matrices.append(m)
    msg = TFMessage(transforms=[transform_to_msg(m, 'base', f'link{k}', 12.25 + k)
                                for k, m in enumerate(matrices)])
    data = serialize_message(msg)
    store = get_typestore(Stores.ROS2_JAZZY)
    theirs = store.deserialize_cdr(data, NAME)
    assert [t.child_frame_id for t in theirs.transforms] == ['link0', 'link1', 'link2']
    for k, (t, m) in enumerate(zip(theirs.transforms, matrices)):
        assert t.header.frame_id == 'base'
        assert t.header.stamp.sec + 1e-9 * t.header.stamp.nanosec == 12.25 + k
        r = t.transform.rotation
        np.testing.assert_allclose(Rotation.from_quat([r.x, r.y, r.z, r.w]).as_matrix(),
                                   m[:3, :3], atol=1e-12)
        tr = t.transform.translation
        np.testing.assert_allclose([tr.x, tr.y, tr.z], m[:3, 3], atol=0)
    # and upstream's bytes read back here
    back = deserialize_message(bytes(store.serialize_cdr(theirs, NAME)), TFMessage)
    assert [stamp_to_sec(t.header.stamp) for t in back.transforms] == [12.25, 13.25, 14.25]
