"""Helpers for testing a graph of nmrm_ros nodes with real processes and real topics (as
`numpy.testing` or ROS's `launch_testing` are for theirs), shared by tests/ and bench/.

    graph    start node executables and `nmrm launch`, capture every nmrm topic in this process,
             finish a process (its exit code and output), read a process's output line by line
    netns    two "machines" on one Linux host (network namespaces; root only)

Failures raise AssertionError (what pytest reports); nothing here is needed to run the package.
"""
