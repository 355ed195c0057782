"""visualization_msgs/Marker from a :mod:`grass_nrsfm_ros.mesh` triangle list (ROS side only).

``vertices: (3T, 3)`` and ``colours: (3T, 4)`` as :func:`grass_nrsfm_ros.mesh.triangle_list`
returns them; the marker is a TRIANGLE_LIST in the header's frame, identity pose, unit scale.
"""
from geometry_msgs.msg import Point
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker

MESH_NAMESPACE = 'grass_nrsfm'


def mesh_marker(vertices, colours, header):
    """A TRIANGLE_LIST Marker (id 0, ADD) of ``vertices`` with per-vertex ``colours``."""
    marker = Marker(header=header, ns=MESH_NAMESPACE, id=0, type=Marker.TRIANGLE_LIST,
                    action=Marker.ADD, frame_locked=False)
    marker.pose.orientation.w = 1.0
    marker.scale.x = marker.scale.y = marker.scale.z = 1.0
    marker.color = ColorRGBA(r=1.0, g=1.0, b=1.0, a=1.0)
    marker.points = [Point(x=x, y=y, z=z) for x, y, z in vertices.tolist()]
    marker.colors = [ColorRGBA(r=r, g=g, b=b, a=a) for r, g, b, a in colours.tolist()]
    return marker
