"""The plan's files: plan.json, plan.npz, the segmentation PLY and the PNG preview.
"""
