"""Thin rclpy adapters: topic names and QoS, message conversions, node entry-point helpers.

Importing this package imports rclpy; the core (`tasks`, `oracles`, `datasets`, `mil`) does not.
"""
