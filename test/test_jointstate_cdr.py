"""The hand-written JointState CDR parser (codec/jointstate_cdr.py) against rclpy's own
(de)serialiser: every field layout, alignment case and rejection, then property-tested.

The parser's promise: for bytes it accepts (parse_layout + verify_layout) and for every
later message that `Layout.matches`, reading through the layout gives exactly what
`rclpy.serialization.deserialize_message` gives; anything else is NotMine (the node then
takes the generic path).
"""

from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState
from support.jointstate import joint_state as _joint_state

from forearm_dynamics.codec.jointstate_cdr import (
    ENCAPSULATION,
    NotMine,
    OutputTemplate,
    parse_layout,
    verified_layout,
    verify_layout,
)

pytestmark = pytest.mark.unit

CDR_BE = b"\x00\x00\x00\x00"  # plain CDR, big endian
XCDR2_LE = b"\x00\x07\x00\x00"  # PLAIN_CDR2, little endian


def joint_state(frame_id="", names=(), position=(), velocity=(), effort=(), stamp=(12, 345)) -> JointState:
    """support.jointstate.joint_state in the order these tests vary the fields; the stamp as
    (sec, nanosec), any nanosec a uint32 holds (the parser must read what it is sent)."""
    msg = _joint_state(0, position, velocity, effort, names=names, frame_id=frame_id)
    msg.header.stamp.sec, msg.header.stamp.nanosec = stamp
    return msg


def encode(msg: JointState, endian: str = "<", encapsulation: bytes = ENCAPSULATION,
           padding: bytes = b"\x00", trailing: int = 0) -> bytes:
    """XCDR1 by hand (alignment relative to byte 4), `padding` repeated into every gap, as
    serializers that leave junk there do; `trailing` extra bytes at the end."""
    out = bytearray(encapsulation)

    def align(n: int) -> None:
        i = 0
        while (len(out) - 4) % n:
            out.append(padding[i % len(padding)])
            i += 1

    def u32(x: int) -> None:
        align(4)
        out.extend(struct.pack(endian + "I", x))

    def string(s: str) -> None:
        b = s.encode("utf-8") + b"\x00"
        u32(len(b))
        out.extend(b)

    align(4)
    out.extend(struct.pack(endian + "iI", msg.header.stamp.sec, msg.header.stamp.nanosec))
    string(msg.header.frame_id)
    u32(len(msg.name))
    for name in msg.name:
        string(name)
    for values in (msg.position, msg.velocity, msg.effort):
        u32(len(values))
        if len(values):
            align(8)
            out.extend(struct.pack(endian + f"{len(values)}d", *values))
    out.extend(padding[:1] * trailing)
    return bytes(out)


def same(a, b) -> bool:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return a.shape == b.shape and bool(np.array_equal(a, b, equal_nan=True))


def read_through(lay, data) -> dict:
    return {"frame_id": lay.frame_id.decode("utf-8"), "name": list(lay.names),
            "position": lay.array(data, "position"), "velocity": lay.array(data, "velocity"),
            "effort": lay.array(data, "effort"), "stamp": struct.unpack_from("<iI", data, 4)}


def assert_reads_like_rclpy(lay, data) -> None:
    msg = deserialize_message(bytes(data), JointState)
    got = read_through(lay, data)
    assert got["frame_id"] == msg.header.frame_id
    assert got["name"] == list(msg.name)
    assert got["stamp"] == (msg.header.stamp.sec, msg.header.stamp.nanosec)
    for field in ("position", "velocity", "effort"):
        assert same(got[field], getattr(msg, field)), field


# -- every field layout ---------------------------------------------------------------------
NAMES_20 = [f"j{i}" for i in range(20)]


@pytest.mark.parametrize("frame_len", range(10))  # frame_id 0..9 bytes: every alignment
@pytest.mark.parametrize(("n_vel", "n_eff"), [(0, 0), (20, 0), (0, 20), (20, 20)])
def test_layouts_frame_id_velocity_effort(frame_len: int, n_vel: int, n_eff: int) -> None:
    rng = np.random.default_rng(frame_len * 100 + n_vel + n_eff)
    msg = joint_state("f" * frame_len, NAMES_20, rng.normal(size=20), rng.normal(size=n_vel),
                      rng.normal(size=n_eff))
    data = serialize_message(msg)
    lay = verified_layout(data)
    assert (lay.n_pos, lay.n_vel, lay.n_eff) == (20, n_vel, n_eff)
    assert lay.frame_id == b"f" * frame_len and lay.names == tuple(NAMES_20)
    for off, n in ((lay.pos_off, 20), (lay.vel_off, n_vel), (lay.eff_off, n_eff)):
        if n:
            assert (off - 4) % 8 == 0, off  # float64 8-aligned relative to the payload
    assert lay.matches(data)
    assert_reads_like_rclpy(lay, data)
    # the same shape with other values, other stamp and junk in every padding byte
    other = joint_state(msg.header.frame_id, NAMES_20, rng.normal(size=20),
                        rng.normal(size=n_vel), rng.normal(size=n_eff), stamp=(99, 7))
    junk = encode(other, padding=b"\xa5\x5a\xff", trailing=len(data) - len(encode(other)))
    assert len(junk) == len(data) and lay.matches(junk)
    assert_reads_like_rclpy(lay, junk)


@pytest.mark.parametrize("name_len", range(9))  # strings of 1..9 bytes with the NUL: every mod 4
def test_names_of_every_length(name_len: int) -> None:
    names = [chr(ord("a") + i) * name_len + str(i) if name_len else str(i) for i in range(7)]
    names[0] = "x" * name_len  # one name of exactly name_len bytes (may be empty)
    msg = joint_state("arm", names, np.arange(7.0), np.arange(7.0) / 2, [])
    data = serialize_message(msg)
    lay = verified_layout(data)
    assert lay.names == tuple(names)
    assert_reads_like_rclpy(lay, data)
    # a name one byte longer shifts every later field: not the cached shape
    longer = list(names)
    longer[0] += "y"
    assert not lay.matches(serialize_message(joint_state("arm", longer, np.arange(7.0),
                                                         np.arange(7.0) / 2, [])))


def test_empty_message() -> None:
    data = serialize_message(JointState())
    lay = verified_layout(data)
    assert (lay.names, lay.n_pos, lay.n_vel, lay.n_eff, lay.frame_id) == ((), 0, 0, 0, b"")
    assert_reads_like_rclpy(lay, data)


# -- rejected to the generic path -------------------------------------------------------------
def test_big_endian_is_not_mine() -> None:
    msg = joint_state("humerus", NAMES_20, np.arange(20.0), np.arange(20.0), [])
    be = encode(msg, endian=">", encapsulation=CDR_BE)
    back = deserialize_message(be, JointState)  # a valid message: rclpy reads big endian
    assert list(back.name) == NAMES_20 and list(back.position) == list(np.arange(20.0))
    with pytest.raises(NotMine):
        parse_layout(be)
    lay = verified_layout(serialize_message(msg))
    assert len(be) != lay.size or not lay.matches(be)
    same_size = be + b"\x00" * (lay.size - len(be)) if len(be) < lay.size else be
    assert not lay.matches(same_size[:lay.size])  # encapsulation checked, not only the size


def test_xcdr2_is_not_mine() -> None:
    msg = joint_state("humerus", NAMES_20, np.arange(20.0), np.arange(20.0), [])
    le = serialize_message(msg)
    x2 = XCDR2_LE + le[4:]
    with pytest.raises(NotMine):
        parse_layout(x2)
    assert not verified_layout(le).matches(x2)


@pytest.mark.parametrize("damage", ["truncated", "no NUL", "huge count", "trailing", "short"])
def test_malformed_is_not_mine(damage: str) -> None:
    data = bytearray(serialize_message(joint_state("arm", ["a", "b"], [1.0, 2.0], [3.0, 4.0])))
    if damage == "truncated":
        data = data[:-9]
    elif damage == "no NUL":  # frame_id "arm" + NUL at 16..19: drop the terminator
        data[19] = ord("x")
    elif damage == "huge count":  # the name count
        struct.pack_into("<I", data, 20, 10**9)
    elif damage == "trailing":
        data += b"\x00" * 64
    else:
        data = data[:12]
    with pytest.raises(NotMine):
        parse_layout(bytes(data))


def test_effort_length_change_on_a_cached_shape_is_not_a_match() -> None:
    """Same size, same names and counts up to velocity, but one effort fewer (its 8 bytes
    left as trailing bytes, which serializers may add): rclpy reads 19 efforts, so the
    cached 20-effort shape must not match (the node then parses it and rejects the
    length mismatch)."""
    msg = joint_state("humerus", NAMES_20, np.arange(20.0), np.arange(20.0), np.arange(20.0))
    data = serialize_message(msg)
    lay = verified_layout(data)
    fewer = joint_state("humerus", NAMES_20, np.arange(20.0), np.arange(20.0), np.arange(19.0))
    crafted = encode(fewer, trailing=lay.size - len(encode(fewer)))
    assert len(crafted) == lay.size
    assert len(deserialize_message(crafted, JointState).effort) == 19
    assert not lay.matches(crafted)
    assert parse_layout(crafted).n_eff == 19  # the generic path sees the real count


def test_verify_layout_catches_a_disagreement() -> None:
    data = serialize_message(joint_state("arm", ["a", "b"], [1.0, 2.0], [3.0, 4.0], [5.0, 6.0]))
    lay = parse_layout(data)
    other = bytearray(serialize_message(joint_state("arm", ["a", "b"], [1.0, 2.0], [3.0, 4.0],
                                                    [5.0, 6.0, 7.0])))
    with pytest.raises(NotMine):
        verify_layout(lay, bytes(other))


def test_output_template_round_trip() -> None:
    tpl = OutputTemplate(NAMES_20, frame_id="humerus", effort=True)
    tpl.q[:] = np.arange(20.0)
    tpl.qd[:] = -np.arange(20.0)
    tpl.effort[:] = np.pi
    tpl.pack_stamp(1_700_000_000, 999_999_999)
    msg = deserialize_message(tpl.payload(), JointState)
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1_700_000_000, 999_999_999)
    assert msg.header.frame_id == "humerus" and list(msg.name) == NAMES_20
    assert list(msg.position) == list(np.arange(20.0))
    assert list(msg.velocity) == list(-np.arange(20.0)) and list(msg.effort) == [np.pi] * 20
    assert tpl.payload() == tpl.layout.zero_padding(tpl.payload())  # padding sent as zeros
    assert tpl.q.ctypes.data % 8 == 0 and tpl.effort.ctypes.data % 8 == 0


# -- property-tested against rclpy ------------------------------------------------------------
TEXT = st.text(st.characters(blacklist_characters="\x00", blacklist_categories=("Cs",)), max_size=9)
FLOATS = st.floats(allow_nan=True, allow_infinity=True)


@st.composite
def messages(draw) -> JointState:
    names = draw(st.lists(TEXT, max_size=24))
    n = len(names)
    sizes = st.sampled_from(sorted({0, n, max(n - 1, 0), n + 1}))
    return joint_state(draw(TEXT), names, draw(st.lists(FLOATS, min_size=n, max_size=n)),
                       draw(st.lists(FLOATS, min_size=(k := draw(sizes)), max_size=k)),
                       draw(st.lists(FLOATS, min_size=(m := draw(sizes)), max_size=m)),
                       stamp=(draw(st.integers(-(2**31), 2**31 - 1)), draw(st.integers(0, 2**32 - 1))))


@pytest.mark.slow  # 300 examples, seconds of CPU: not in `-m unit`
@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(msg=messages(), other=messages(), junk=st.binary(min_size=1, max_size=7),
       slack=st.integers(0, 16))
def test_property_agrees_with_rclpy(msg, other, junk, slack) -> None:
    data = serialize_message(msg)
    lay = verified_layout(data)  # never NotMine for rclpy's own little-endian output
    assert lay.matches(data)
    assert_reads_like_rclpy(lay, data)
    # the same message with junk padding and trailing bytes: same shape, same reading
    hand = encode(msg, padding=junk, trailing=slack)
    assert deserialize_message(hand, JointState).name == msg.name
    lay2 = verified_layout(hand)
    assert (lay2.names, lay2.n_pos, lay2.n_vel, lay2.n_eff) == (lay.names, lay.n_pos, lay.n_vel, lay.n_eff)
    if len(hand) == lay.size:
        assert lay.matches(hand)
    # any other message the cached shape matches reads exactly as rclpy reads it
    for candidate in (serialize_message(other), encode(other, padding=junk, trailing=slack)):
        if lay.matches(candidate):
            assert_reads_like_rclpy(lay, candidate)
