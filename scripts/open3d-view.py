#!/usr/bin/env python3
"""Open `epd estimate FRAME --export-fit FIT.ply` in Open3D's viewer and save what it shows.

The measured points (`mesh` 0) coloured by `residual_mm` (blue inside the fitted wall,
white on it, red beyond; saturated at 3 robust σ of the residuals, 1.4826·MAD), and the
fitted wall's triangles (`mesh` 1: the straight section, and the bend's torus when one was
found) drawn as a grey wire frame. The PLY is read by Open3D itself
(`read_triangle_mesh`) and by `plyfile` (the residuals), readers this project did not write.

    pip install open3d plyfile numpy          # open3d also needs libusb-1.0 (apt: libusb-1.0-0)
    xvfb-run -a python3 scripts/open3d-view.py fit.ply fit.png   # headless: apt xvfb

Sensor frame as `epd` writes it by default (X forward along the pipe, Z up).
"""
import sys
import numpy as np
import open3d as o3d
from plyfile import PlyData

if len(sys.argv) != 3:
    sys.exit("usage: open3d-view.py FIT.ply OUT.png")
src, out = sys.argv[1], sys.argv[2]
v = PlyData.read(src)["vertex"].data
pts = v[v["mesh"] == 0]
xyz = np.stack([pts[c] for c in "xyz"], axis=1)
res = np.asarray(pts["residual_mm"], dtype=float)
lim = 3 * 1.4826 * np.median(np.abs(res - np.median(res)))
t = np.clip(res / lim, -1, 1)
col = np.stack([np.where(t > 0, 1, 1 + t), 1 - np.abs(t), np.where(t < 0, 1, 1 - t)], axis=1)
pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz))
pc.colors = o3d.utility.Vector3dVector(col)
mesh = o3d.io.read_triangle_mesh(src)
mesh.remove_unreferenced_vertices()
wire = o3d.geometry.LineSet.create_from_triangle_mesh(mesh)
wire.paint_uniform_color([0.55, 0.55, 0.55])
vis = o3d.visualization.Visualizer()
vis.create_window(width=1000, height=700, visible=False)
vis.add_geometry(pc)
vis.add_geometry(wire)
ctr = vis.get_view_control()
ctr.set_front([-0.35, -0.85, 0.4])
ctr.set_up([0, 0, 1])
ctr.set_lookat([1.3, 0.0, 0.0])
ctr.set_zoom(0.45)
opt = vis.get_render_option()
opt.point_size = 1.5
vis.poll_events(); vis.update_renderer()
vis.capture_screen_image(out, do_render=True)
vis.destroy_window()
print("points", len(xyz), "wall triangles", len(mesh.triangles), "colour limit ±%.1f mm" % lim)
