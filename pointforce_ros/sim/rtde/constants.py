"""Constants of the emulated controller: ports, versions, modes, bits, script command numbers.

The command numbers are those of ur_rtde 1.6.5's control script (input_int_register_0).
"""


DT = 0.002
"""Controller period, s (e-Series: 500 Hz)."""

RTDE_PORT = 30004
DASHBOARD_PORT = 29999
SCRIPT_PORT = 30003
CONTROL_PORT = 30099

CONTROLLER_VERSION = (5, 11, 1, 108318)
POLYSCOPE_TEXT = 'URSoftware 5.11.1.108318 (Jan 25 2022)'
SERIAL_NUMBER = '20205500001'

# runtime_state values (RTDE guide)
RUNTIME_STOPPED = 1
RUNTIME_PLAYING = 2
RUNTIME_PAUSED = 4

ROBOT_MODE_RUNNING = 7
SAFETY_MODE_NORMAL = 1
SAFETY_MODE_PROTECTIVE_STOP = 3
SAFETY_BIT_NORMAL = 1 << 0
SAFETY_BIT_PROTECTIVE_STOPPED = 1 << 2
SAFETY_BIT_STOPPED_DUE_TO_SAFETY = 1 << 10
ROBOT_BIT_POWER_ON = 1 << 0
ROBOT_BIT_PROGRAM_RUNNING = 1 << 1
JOINT_MODE_RUNNING = 253

READY = 1
DONE = 2

# ur_rtde control-script command numbers (input_int_register_0)
CMD_MOVEL = 3
CMD_FORCE_MODE_STOP = 7
CMD_ZERO_FT = 8
CMD_SPEEDL = 10
CMD_SPEED_STOP = 15
CMD_SERVO_STOP = 16
CMD_SET_PAYLOAD = 17
CMD_TOOL_CONTACT = 25
CMD_GET_STEPTIME = 26
CMD_GET_TARGET_WAYPOINT = 28
CMD_SET_TCP = 29
CMD_PROTECTIVE_STOP = 31
CMD_STOPL = 33
CMD_STOPJ = 34
CMD_SET_WATCHDOG = 35
CMD_IS_POSE_SAFE = 36
CMD_POSE_TRANS = 39
CMD_GET_TCP_OFFSET = 40
CMD_FK_DEFAULT = 43
CMD_IS_STEADY = 47
CMD_MOVE_UNTIL_CONTACT = 51
CMD_FLANGE_POSE = 58
CMD_START_CONTACT = 62
CMD_STOP_CONTACT = 63
CMD_READ_CONTACT = 64
CMD_SET_TARGET_PAYLOAD = 65
CMD_INTERNAL_CONTACT = 254
CMD_STOP_SCRIPT = 255

REALTIME_COMMANDS = frozenset({24, 11, 9, 10, 6, 25, 26, 27, 38, 58})
"""Commands the control script processes and answers READY in the same cycle."""

UNSUPPORTED = {1: 'moveJ', 2: 'moveJ_IK', 4: 'moveL_FK', 6: 'forceMode', 9: 'speedJ',
               11: 'servoJ', 12: 'servoC', 24: 'servoL', 27: 'getActualJointPositionsHistory',
               30: 'getInverseKinematics', 41: 'jogStart', 45: 'movePath',
               52: 'freedriveMode'}
"""Commands with no kinematic model here: they stop the program with a script error."""

PROTECTIVE_DECEL = 5.0
"""Deceleration of a protective stop, m/s^2 (and rad/s^2)."""
PROGRAM_STOP_DECEL = 3.0
CONTACT_STOP_DECEL = 3.0
CONTACT_RETURN_SPEED = 0.25
CONTACT_RETURN_ACCEL = 1.2
TARE_SAMPLES = 10
HISTORY = 1000
