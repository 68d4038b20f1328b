"""Marker tracking: template + constant-velocity Kalman per marker and camera, stereo-consistent.

Project-level entry points live in `run` (auto_seed, accept_seeds, seed_marker, track_project)
and `seeding` (snap_to_marker). One time step over all markers is `engine.Engine.step`, its stages in
modules of their own (engine.py lists them).
"""
