"""Geometry every stage may use and that uses no stage: rasters, orthonormal bases, the tool assembly
(cutter, shank, holder), the fixtures, and the collision queries of the tool against points and fixtures.
"""
