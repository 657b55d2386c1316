"""ROS bags (ROS 2 with MCAP or SQLite storage, ROS 1) read into runs.

- ``bag``: opens a bag with ``rosbags`` and gives each topic's raw messages;
- ``columns``: turns a topic's raw messages into arrays of the fields asked for;
- ``topic_map``: the vehicle file's ``[ros]`` table, and which topic plays which part;
- ``to_run``: stamps, overlap, a uniform grid, the IMU's mounting: a ``Run``.
"""
