"""Viewing a running graph from outside ROS: the Foxglove WebSocket server."""
