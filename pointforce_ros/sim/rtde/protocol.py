"""Wire format of the UR Real-Time Data Exchange (RTDE) protocol, version 2, server side.

Facts used here (UR RTDE guide, and ur_rtde 1.6.x as published):

- Every message is ``>HB`` (total size including the 3-byte header, message type byte) followed
  by a big-endian payload.
- Message types are ASCII letters: ``V`` request protocol version, ``v`` get controller
  version, ``O`` set up outputs, ``I`` set up inputs, ``S`` start, ``P`` pause, ``U`` data
  package, ``M`` text message.
- ``O`` carries a ``>d`` frequency and comma-separated variable names; the reply is a recipe id
  byte and comma-separated type names (``NOT_FOUND`` for an unknown name). ``I`` carries names
  only; the reply is the same, with ``IN_USE`` for a register another client already writes.
- A data package ``U`` is a recipe id byte followed by the recipe's values in order.

This module holds no sockets and no threads, so it is cheap to test and to reuse.
"""

from dataclasses import dataclass
import struct
from typing import Callable, Dict, Iterator, List, Mapping, Sequence, Tuple

HEADER = struct.Struct('>HB')
"""Message header: total size in bytes (header included) and message type."""

MSG_REQUEST_PROTOCOL_VERSION = ord('V')
MSG_GET_URCONTROL_VERSION = ord('v')
MSG_TEXT_MESSAGE = ord('M')
MSG_DATA_PACKAGE = ord('U')
MSG_SETUP_OUTPUTS = ord('O')
MSG_SETUP_INPUTS = ord('I')
MSG_START = ord('S')
MSG_PAUSE = ord('P')

PROTOCOL_VERSION = 2
MAX_MESSAGE_SIZE = 0xFFFF

TYPE_FORMATS: Dict[str, str] = {
    'BOOL': '?',
    'UINT8': 'B',
    'UINT32': 'I',
    'UINT64': 'Q',
    'INT32': 'i',
    'DOUBLE': 'd',
    'VECTOR3D': '3d',
    'VECTOR6D': '6d',
    'VECTOR6INT32': '6i',
    'VECTOR6UINT32': '6I',
}
"""RTDE type name -> struct format of one value of that type."""

TYPE_WIDTH: Dict[str, int] = {'VECTOR3D': 3, 'VECTOR6D': 6, 'VECTOR6INT32': 6,
                              'VECTOR6UINT32': 6}
"""Number of scalars of a vector type (scalar types are absent: width one)."""


def _output_variables() -> Dict[str, str]:
    table = {
        'timestamp': 'DOUBLE',
        'target_q': 'VECTOR6D', 'target_qd': 'VECTOR6D', 'target_qdd': 'VECTOR6D',
        'target_current': 'VECTOR6D', 'target_moment': 'VECTOR6D',
        'actual_q': 'VECTOR6D', 'actual_qd': 'VECTOR6D', 'actual_qdd': 'VECTOR6D',
        'actual_current': 'VECTOR6D', 'actual_current_window': 'VECTOR6D',
        'actual_moment': 'VECTOR6D', 'actual_current_as_torque': 'VECTOR6D',
        'joint_control_output': 'VECTOR6D',
        'actual_TCP_pose': 'VECTOR6D', 'actual_TCP_speed': 'VECTOR6D',
        'actual_TCP_force': 'VECTOR6D', 'target_TCP_pose': 'VECTOR6D',
        'target_TCP_speed': 'VECTOR6D', 'ft_raw_wrench': 'VECTOR6D',
        'actual_digital_input_bits': 'UINT64', 'actual_digital_output_bits': 'UINT64',
        'joint_temperatures': 'VECTOR6D', 'actual_execution_time': 'DOUBLE',
        'robot_mode': 'INT32', 'joint_mode': 'VECTOR6INT32', 'safety_mode': 'INT32',
        'safety_status': 'INT32', 'actual_tool_accelerometer': 'VECTOR3D',
        'speed_scaling': 'DOUBLE', 'target_speed_fraction': 'DOUBLE',
        'actual_momentum': 'DOUBLE', 'actual_main_voltage': 'DOUBLE',
        'actual_robot_voltage': 'DOUBLE', 'actual_robot_current': 'DOUBLE',
        'actual_joint_voltage': 'VECTOR6D', 'runtime_state': 'UINT32',
        'elbow_position': 'VECTOR3D', 'elbow_velocity': 'VECTOR3D',
        'robot_status_bits': 'UINT32', 'safety_status_bits': 'UINT32',
        'analog_io_types': 'UINT32',
        'standard_analog_input0': 'DOUBLE', 'standard_analog_input1': 'DOUBLE',
        'standard_analog_output0': 'DOUBLE', 'standard_analog_output1': 'DOUBLE',
        'io_current': 'DOUBLE',
        'euromap67_input_bits': 'UINT32', 'euromap67_output_bits': 'UINT32',
        'euromap67_24V_voltage': 'DOUBLE', 'euromap67_24V_current': 'DOUBLE',
        'tool_mode': 'UINT32', 'tool_analog_input_types': 'UINT32',
        'tool_analog_input0': 'DOUBLE', 'tool_analog_input1': 'DOUBLE',
        'tool_output_voltage': 'INT32', 'tool_output_current': 'DOUBLE',
        'tool_temperature': 'DOUBLE', 'tcp_force_scalar': 'DOUBLE',
        'tool_output_mode': 'UINT8', 'tool_digital_output0_mode': 'UINT8',
        'tool_digital_output1_mode': 'UINT8',
        'output_bit_registers0_to_31': 'UINT32', 'output_bit_registers32_to_63': 'UINT32',
        'input_bit_registers0_to_31': 'UINT32', 'input_bit_registers32_to_63': 'UINT32',
        'payload': 'DOUBLE', 'payload_cog': 'VECTOR3D', 'payload_inertia': 'VECTOR6D',
        'script_control_line': 'UINT32', 'joint_position_deviation_ratio': 'DOUBLE',
        'collision_detection_ratio': 'DOUBLE', 'time_scale_source': 'UINT32',
    }
    for i in range(48):
        table[f'output_int_register_{i}'] = 'INT32'
        table[f'output_double_register_{i}'] = 'DOUBLE'
        table[f'input_int_register_{i}'] = 'INT32'
        table[f'input_double_register_{i}'] = 'DOUBLE'
    for i in range(64, 128):
        table[f'output_bit_register_{i}'] = 'BOOL'
        table[f'input_bit_register_{i}'] = 'BOOL'
    return table


def _input_variables() -> Dict[str, str]:
    table = {
        'speed_slider_mask': 'UINT32', 'speed_slider_fraction': 'DOUBLE',
        'standard_digital_output_mask': 'UINT8', 'standard_digital_output': 'UINT8',
        'configurable_digital_output_mask': 'UINT8', 'configurable_digital_output': 'UINT8',
        'tool_digital_output_mask': 'UINT8', 'tool_digital_output': 'UINT8',
        'standard_analog_output_mask': 'UINT8', 'standard_analog_output_type': 'UINT8',
        'standard_analog_output_0': 'DOUBLE', 'standard_analog_output_1': 'DOUBLE',
        'input_bit_registers0_to_31': 'UINT32', 'input_bit_registers32_to_63': 'UINT32',
        'external_force_torque': 'VECTOR6D',
    }
    for i in range(48):
        table[f'input_int_register_{i}'] = 'INT32'
        table[f'input_double_register_{i}'] = 'DOUBLE'
    for i in range(64, 128):
        table[f'input_bit_register_{i}'] = 'BOOL'
    return table


OUTPUT_VARIABLES: Dict[str, str] = _output_variables()
"""Controller -> client variable name -> RTDE type."""

INPUT_VARIABLES: Dict[str, str] = _input_variables()
"""Client -> controller variable name -> RTDE type."""


class ProtocolError(ValueError):
    """A peer sent bytes that are not a valid RTDE message."""


def encode_message(msg_type: int, payload: bytes = b'') -> bytes:
    """Frame ``payload`` as one RTDE message of type ``msg_type``.

    Raises:
        ProtocolError: the framed message would exceed 65535 bytes.

    """
    size = HEADER.size + len(payload)
    if size > MAX_MESSAGE_SIZE:
        raise ProtocolError(f'message of {size} bytes exceeds the RTDE limit of 65535')
    return HEADER.pack(size, msg_type) + payload


class MessageBuffer:
    """Reassembles RTDE messages from a byte stream (TCP delivers arbitrary chunks)."""

    def __init__(self):
        self._buf = bytearray()

    def feed(self, data: bytes) -> Iterator[Tuple[int, bytes]]:
        """Append ``data`` and yield every complete ``(msg_type, payload)`` now available.

        Raises:
            ProtocolError: a header announces a size smaller than the header itself.

        """
        self._buf.extend(data)
        while len(self._buf) >= HEADER.size:
            size, msg_type = HEADER.unpack_from(self._buf, 0)
            if size < HEADER.size:
                raise ProtocolError(f'message header announces {size} bytes (< 3)')
            if len(self._buf) < size:
                return
            payload = bytes(self._buf[HEADER.size:size])
            del self._buf[:size]
            yield msg_type, payload


@dataclass(frozen=True)
class Recipe:
    """One negotiated RTDE recipe: an id and an ordered list of typed variables.

    Attributes:
        recipe_id: 1..255, the first byte of every data package of this recipe.
        names: variable names in package order.
        types: RTDE type names, same order.

    """

    recipe_id: int
    names: Tuple[str, ...]
    types: Tuple[str, ...]

    def __post_init__(self):
        fmt = '>' + ''.join(TYPE_FORMATS[t] for t in self.types)
        object.__setattr__(self, '_struct', struct.Struct(fmt))

    @property
    def size(self) -> int:
        """Bytes of one data package body, recipe id excluded."""
        return self._struct.size

    def pack(self, value_of: Callable[[str], object]) -> bytes:
        """Return a complete framed ``U`` message with the current value of every variable.

        ``value_of(name)`` returns a scalar or a sequence (vector types).
        """
        flat: List[object] = []
        for name, typ in zip(self.names, self.types):
            value = value_of(name)
            if typ in TYPE_WIDTH:
                flat.extend(value)
            else:
                flat.append(value)
        return encode_message(MSG_DATA_PACKAGE,
                              bytes((self.recipe_id,)) + self._struct.pack(*flat))

    def unpack(self, body: bytes) -> Dict[str, object]:
        """Decode a data package body (recipe id byte excluded) into ``{name: value}``.

        Raises:
            ProtocolError: the body length does not match the recipe.

        """
        if len(body) != self._struct.size:
            raise ProtocolError(f'recipe {self.recipe_id}: data package of {len(body)} bytes, '
                                f'expected {self._struct.size}')
        flat = self._struct.unpack(body)
        out: Dict[str, object] = {}
        pos = 0
        for name, typ in zip(self.names, self.types):
            width = TYPE_WIDTH.get(typ, 1)
            out[name] = flat[pos] if width == 1 else tuple(flat[pos:pos + width])
            pos += width
        return out


def parse_names(text: bytes) -> List[str]:
    """Split a comma-separated (usually comma-terminated) variable list."""
    return [n for n in text.decode('ascii', errors='replace').split(',') if n]


def resolve_types(names: Sequence[str], table: Mapping[str, str]) -> List[str]:
    """RTDE type of each name, ``NOT_FOUND`` for a name ``table`` does not know."""
    return [table.get(name, 'NOT_FOUND') for name in names]


def setup_reply(msg_type: int, recipe_id: int, types: Sequence[str]) -> bytes:
    """Framed reply to ``O`` or ``I``: recipe id (0 when refused) and the type list."""
    return encode_message(msg_type, bytes((recipe_id,)) + ','.join(types).encode('ascii'))
