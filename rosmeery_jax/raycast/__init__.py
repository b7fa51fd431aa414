"""Exact ray casting against boxes and the floor, and the sensors built on it: the planar
laser, the depth + segmentation camera and the RGB camera."""
