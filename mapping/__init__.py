"""Dense static map: the depth of map views back-projected, fused on a voxel grid, cleaned, saved.

Open3D is imported only by the steps that need it (cleaning, TSDF, PLY output), so
importing this package stays cheap.
"""
