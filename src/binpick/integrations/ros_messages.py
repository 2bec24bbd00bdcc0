"""Messages both ROS nodes publish beside their answers, built the same way in either ROS: ROS 1's
genpy messages and ROS 2's rosidl ones share their Python names and fields, and each node imports
this module in its own interpreter (ROS 1's Debian packages, or the ROS 2 wheels), so the
``geometry_msgs``/``visualization_msgs`` imported here are that ROS's.
"""

from __future__ import annotations


def pose_of(position, orientation):
    """``geometry_msgs/Pose`` from a position (m) and a quaternion x, y, z, w."""
    import geometry_msgs.msg

    pose = geometry_msgs.msg.Pose()
    pose.position.x, pose.position.y, pose.position.z = (float(v) for v in position)
    pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w = (float(v) for v in orientation)
    return pose


def pose_array(grasps, frame: str, stamp):
    """``geometry_msgs/PoseArray`` of planned grasps (best first)."""
    import geometry_msgs.msg

    message = geometry_msgs.msg.PoseArray()
    message.header.frame_id, message.header.stamp = frame, stamp
    message.poses = [pose_of(p.position, p.orientation) for p in grasps]
    return message


def transform_stamped(pose, stamp):
    """``geometry_msgs/TransformStamped`` of a :class:`~binpick.picking.scene_messages.FramePose`."""
    import geometry_msgs.msg

    message = geometry_msgs.msg.TransformStamped()
    message.header.frame_id, message.header.stamp, message.child_frame_id = pose.parent, stamp, pose.child
    t, r = message.transform.translation, message.transform.rotation
    t.x, t.y, t.z = (float(v) for v in pose.translation)
    r.x, r.y, r.z, r.w = (float(v) for v in pose.rotation)
    return message


def tf_message(poses, stamp):
    """``tf2_msgs/TFMessage`` (what ``/tf`` and ``/tf_static`` carry) of frame poses."""
    import tf2_msgs.msg

    return tf2_msgs.msg.TFMessage(transforms=[transform_stamped(pose, stamp) for pose in poses])


def marker_array(specs, frame: str, stamp):
    """``visualization_msgs/MarkerArray``: a DELETEALL first (the last answer's markers go), then ``specs``
    (:class:`~binpick.picking.scene_messages.MarkerSpec`)."""
    import visualization_msgs.msg

    Marker = visualization_msgs.msg.Marker
    clear = Marker(action=Marker.DELETEALL)
    clear.header.frame_id, clear.header.stamp = frame, stamp
    markers = [clear]
    for spec in specs:
        marker = Marker(ns=spec.namespace, id=spec.marker_id, type=spec.type_code, action=Marker.ADD, text=spec.text)
        marker.header.frame_id, marker.header.stamp = frame, stamp
        marker.pose = pose_of(spec.position, spec.orientation)
        marker.scale.x, marker.scale.y, marker.scale.z = (float(v) for v in spec.scale)
        marker.color.r, marker.color.g, marker.color.b, marker.color.a = (float(v) for v in spec.colour)
        markers.append(marker)
    return visualization_msgs.msg.MarkerArray(markers=markers)
