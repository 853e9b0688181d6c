//! Laser scans: simulated from a map, read from a sensor, reduced to obstacle points (issue 53).
