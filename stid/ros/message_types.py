"""The message types stid reads, and the fields it takes from each.

Bags written by ``ros2 bag record`` (MCAP) and ROS 1 bags carry their message
definitions, and ``rosbags`` decodes them from those. A bag without definitions (ROS 2
SQLite bags before Iron) is decoded with the standard definitions of its ROS
generation, plus ``ackermann_msgs``, which is not among rosbags' built-in types.
"""

from __future__ import annotations

IMU = "sensor_msgs/msg/Imu"
ODOMETRY = "nav_msgs/msg/Odometry"
ACKERMANN = "ackermann_msgs/msg/AckermannDriveStamped"
FLOAT64 = "std_msgs/msg/Float64"

STAMP = ["header.stamp.sec", "header.stamp.nanosec"]
# REP 145: sensor_msgs/Imu in m/s^2 and rad/s, in the frame of header.frame_id
FIELDS = {
    IMU: STAMP + ["linear_acceleration.x", "linear_acceleration.y", "linear_acceleration.z",
                  "angular_velocity.x", "angular_velocity.y", "angular_velocity.z"],
    # REP 105: the twist is in the child frame (the car's body): linear.x is the forward speed
    ODOMETRY: STAMP + ["twist.twist.linear.x", "twist.twist.linear.y", "twist.twist.angular.z"],
    # steering_angle: the front road-wheel angle [rad], left positive (ackermann_msgs)
    ACKERMANN: STAMP + ["drive.steering_angle"],
    # a servo command (the VESC's commands/servo/position, 0-1): no header, no unit
    FLOAT64: ["data"],
}

# ackermann_msgs (ROS 1 and ROS 2 alike; public definitions)
_ACKERMANN_DRIVE = """float32 steering_angle
float32 steering_angle_velocity
float32 speed
float32 acceleration
float32 jerk
"""
_ACKERMANN_STAMPED = """std_msgs/Header header
ackermann_msgs/AckermannDrive drive
"""


def default_typestore(kind: str):
    """The typestore for a bag that carries no message definitions."""
    from rosbags.typesys import Stores, get_typestore, get_types_from_msg

    store = get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)
    types = get_types_from_msg(_ACKERMANN_DRIVE, "ackermann_msgs/msg/AckermannDrive")
    types.update(get_types_from_msg(_ACKERMANN_STAMPED, ACKERMANN))
    store.register(types)
    return store
