"""ROS message codecs: sensor_msgs/JointState as CDR bytes (the nodes' fast path) and the
one JointState reader of bags."""
