"""A run as ROS 2 sees it, with no ROS installed: names, rmw_zenoh's wire layout, message types.

- ``names``: the ROS 2 name rules, and where a run's topics are (one namespace per vehicle);
- ``wire``: rmw_zenoh's layout: a topic's data key, the liveliness tokens of a node and of a
  publisher (with its QoS), a publication's 33-byte attachment;
- ``types``: the message types a run uses (ROS 2's and ours, ``msg/*.msg``), their type hashes
  (RIHS01) and CDR encoding, through ``rosbags``' type store; ``messages``: each message built
  from our arrays, once; ``publisher``: one ROS 2 publisher on a zenoh session.

What uses them: ``rundir.ros2_bag`` (a run directory as a rosbag2 file), ``running.ros2_face``
(a running swarm on ROS 2 topics), ``nodes.ros2_controller`` (a follower a ROS 2 node flies) and
the config's ``ros2:`` section.

May import: nothing of ours.
"""
