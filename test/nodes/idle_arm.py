"""A stand-in for the poke server's arm (``UrArm``) in node tests that do not drive a robot.

The real driver is tested against the RTDE controller emulator (``test/e2e``); these node tests
check the ROS side, so the arm only has to be connected. Subclasses add a push.
"""


class IdleArm:
    """An arm that is connected and never moves (the poke server connects at start-up)."""

    def __init__(self, host):
        self.host = host

    def add_sample_callback(self, callback):
        pass

    def is_connected(self):
        return True

    def close(self):
        pass

    def latest(self):
        return None

    def tare(self):
        pass
