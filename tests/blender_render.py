"""Render an exported Blender script with Blender itself (Cycles), for tests/test_export.py.

Run with a Python that has Blender's ``bpy`` module (``bash .ci/setup.sh --tests`` makes ``.venv-blender``)::

    python tests/blender_render.py SCRIPT OUT.exr --size N --cam-z Z --light X,Y,Z --power P --spp S

It starts from Blender's empty factory scene (no world: black surroundings), runs ``SCRIPT`` (the
export's ``material_blender.py``: a 2 x 2 plane at z = 0 with the material), adds a point light of
radius 0 with ``P`` watts at the light position and a perspective camera at (0, 0, Z) looking down
-Z (+Y up) whose horizontal field of view ``2 atan(1 / Z)`` sees exactly the [-1, 1]^2 plane, and
renders N x N pixels with Cycles on the CPU: no denoising, a pixel filter of 0.01 px (each pixel
samples the plane at its centre, i.e. at a texel centre when N is the texture's size), direct light
only (``max_bounces = 0``: nothing else is in the scene). The image is written as a linear 32-bit
OpenEXR (scene-linear: no view transform). Blender's point light of P watts has radiant intensity
``P / (4 pi^2)`` in the units where our texel renderer's intensity I gives the radiance
``f pi I cos / d^2`` (a white Lambertian texel facing the light at distance d: ``I / d^2``).
"""
from __future__ import annotations

import argparse
import math
import runpy

import bpy


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n", 1)[0])
    parser.add_argument("script")
    parser.add_argument("out")
    parser.add_argument("--size", type=int, required=True)
    parser.add_argument("--cam-z", type=float, required=True)
    parser.add_argument("--light", required=True, help="x,y,z")
    parser.add_argument("--power", type=float, required=True, help="point light power, W")
    parser.add_argument("--spp", type=int, default=4)
    args = parser.parse_args()

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.world = None
    runpy.run_path(args.script, run_name="__main__")

    light_data = bpy.data.lights.new("light", "POINT")
    light_data.energy = args.power
    light_data.shadow_soft_size = 0.0
    light = bpy.data.objects.new("light", light_data)
    light.location = tuple(float(v) for v in args.light.split(","))
    scene.collection.objects.link(light)
    camera_data = bpy.data.cameras.new("camera")
    camera_data.sensor_fit = "HORIZONTAL"
    camera_data.angle = 2.0 * math.atan(1.0 / args.cam_z)
    camera = bpy.data.objects.new("camera", camera_data)
    camera.location = (0.0, 0.0, args.cam_z)
    scene.collection.objects.link(camera)
    scene.camera = camera

    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = args.spp
    scene.cycles.use_denoising = False
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.filter_width = 0.01
    scene.cycles.max_bounces = 0
    scene.render.resolution_x = scene.render.resolution_y = args.size
    scene.render.resolution_percentage = 100
    scene.view_settings.view_transform = "Standard"
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.image_settings.color_depth = "32"
    scene.render.filepath = args.out
    bpy.ops.render.render(write_still=True)


if __name__ == "__main__":
    main()
