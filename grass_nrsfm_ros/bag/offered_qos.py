"""Offered QoS profiles as rosbag2 (Jazzy, metadata version 9) records them.

rosbag2 stores, per topic, the QoS each publisher offered: in the MCAP channel metadata
(``offered_qos_profiles``, a YAML string) and in ``metadata.yaml`` (the same list, as YAML).
Each profile is a mapping with policy names in lower case (``keep_last``, ``best_effort``,
``volatile``, ``automatic``; ``unknown`` for a policy discovery does not report) and durations
as ``{sec, nsec}`` (``RMW_DURATION_INFINITE`` = 9223372036 s 854775807 ns).

No ROS import: a profile is anything with rclpy's ``QoSProfile`` attributes (enum policies
with ``.name``, durations with ``.nanoseconds``), e.g. ``TopicEndpointInfo.qos_profile``.
"""
import yaml

KEYS = ('history', 'depth', 'reliability', 'durability', 'deadline', 'lifespan', 'liveliness',
        'liveliness_lease_duration', 'avoid_ros_namespace_conventions')


def _duration(d):
    sec, nsec = divmod(int(d.nanoseconds), 1_000_000_000)
    return {'sec': sec, 'nsec': nsec}


def profile_dict(profile):
    """One profile as the mapping rosbag2 writes (keys in :data:`KEYS` order)."""
    return {'history': profile.history.name.lower(), 'depth': int(profile.depth),
            'reliability': profile.reliability.name.lower(),
            'durability': profile.durability.name.lower(),
            'deadline': _duration(profile.deadline), 'lifespan': _duration(profile.lifespan),
            'liveliness': profile.liveliness.name.lower(),
            'liveliness_lease_duration': _duration(profile.liveliness_lease_duration),
            'avoid_ros_namespace_conventions': bool(profile.avoid_ros_namespace_conventions)}


def offered_qos_yaml(profiles):
    """The ``offered_qos_profiles`` string (block YAML list; '' for no profiles)."""
    dicts = [profile_dict(p) for p in profiles]
    return yaml.safe_dump(dicts, sort_keys=False, default_flow_style=False).strip() \
        if dicts else ''


def offered_qos_list(text):
    """The list of profile mappings in an ``offered_qos_profiles`` string ([] for '')."""
    return yaml.safe_load(text) or [] if text else []
