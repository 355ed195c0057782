"""The reconstruction node's ``tracks`` subscription and its reliability (docs/decisions/0300).

``input_reliability``: 'auto' subscribes reliable while every publisher found offers reliable,
best effort (REP 2003's sensor data, as image_proc does) otherwise and while none is found, and
resubscribes as publishers come and go (:meth:`InputSubscription.adapt`, once a second);
'best_effort' / 'reliable' fix it; a ``qos_overrides.<tracks>.subscription.reliability``
parameter pins it. The history is INPUT_DEPTH frames: a stall of the executor delays frames
instead of overwriting them unseen. Messages arrive raw (CDR bytes, recorded as received).
"""
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2

INPUT_DEPTH = 100            # tracks messages the node's reader keeps (3 s at 30 Hz)
RELIABILITY = {'reliable': ReliabilityPolicy.RELIABLE,
               'best_effort': ReliabilityPolicy.BEST_EFFORT}


class InputSubscription:
    """The raw ``topic`` subscription of ``node`` calling ``callback(raw)``; see the module
    docstring. ``subscription``: the current rclpy Subscription."""

    def __init__(self, node, topic, callback, mode, *, callback_group=None, overrides=None):
        self._node, self._topic, self._callback = node, topic, callback
        self._group, self.mode = callback_group, mode
        self._pinned = self._overridden()
        asked = self._wanted() if mode == 'auto' else RELIABILITY[mode]
        self.subscription = self._subscribe(asked, overrides)

    @property
    def reliability(self):
        return self.subscription.qos_profile.reliability

    def adapt(self):
        """'auto': resubscribe when the publishers found call for the other reliability;
        returns the new reliability then, else None."""
        if self.mode != 'auto' or self._pinned:
            return None
        wanted = self._wanted()
        if wanted == self.reliability:
            return None
        self._node.destroy_subscription(self.subscription)
        self.subscription = self._subscribe(wanted)
        return wanted

    def _overridden(self):
        """Whether a ``qos_overrides.<topic>.subscription.reliability`` parameter was given
        (declared for a moment with an empty default; the override, if any, replaces it)."""
        name = (f'qos_overrides.{self._node.resolve_topic_name(self._topic)}'
                '.subscription.reliability')
        given = self._node.declare_parameter(
            name, '', ParameterDescriptor(dynamic_typing=True)).value
        self._node.undeclare_parameter(name)
        return given != ''

    def _subscribe(self, reliability, overrides=None):
        kwargs = {} if overrides is None else {'qos_overriding_options': overrides}
        return self._node.create_subscription(
            PointCloud2, self._topic, self._callback,
            QoSProfile(depth=INPUT_DEPTH, reliability=reliability), raw=True,
            callback_group=self._group, **kwargs)

    def _wanted(self):
        """RELIABLE while every publisher found offers reliable; BEST_EFFORT otherwise."""
        infos = self._node.get_publishers_info_by_topic(
            self._node.resolve_topic_name(self._topic))
        if infos and all(i.qos_profile.reliability == ReliabilityPolicy.RELIABLE
                         for i in infos):
            return ReliabilityPolicy.RELIABLE
        return ReliabilityPolicy.BEST_EFFORT
