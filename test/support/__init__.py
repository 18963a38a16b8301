"""Test support shared by every test module (not installed, not a test module itself).

- support.jointstate: the one JointState builder (and stamp helpers) every test uses.
- support.torque_harness: the one torque_node harness: a real node process and an rclpy peer
  that feeds it and collects its answers and diagnostics.
- support.colcon: the one colcon build of a clean copy of the checkout (test_colcon,
  test_ros_tools).
- support.two_host_replay: the one two-host replay (publisher and recorder in host B against
  a torque node in host A, check_bag on B's bag).

Beside it, in test/: rosproc (start real node processes on a private loopback domain; Procs,
behind conftest's `procs` and `module_procs` fixtures), faultkit (the fault suite's pieces),
bagkit (synthetic bags), trajectories (smooth analytic trajectories). docs/testing.md has the
tiers and which fixture to use for what.
"""
