"""Code that runs inside Blender (``import bpy``): a thin API in the BlenderProc spirit.

- :mod:`frng.blender.scene`     -- Cycles CPU scene, camera from an OpenCV c2w, G-buffer passes, render to file
- :mod:`frng.blender.objects`   -- mesh import (OBJ/PLY/STL/glTF), primitives, procedural shapes, normalisation
- :mod:`frng.blender.materials` -- Principled BSDF materials (diffuse/specular, textures), fur, AOV outputs
- :mod:`frng.blender.world`     -- environment-map world, sky baking

Only the curation and env-map stages import these modules; nothing else in ``frng`` needs bpy.
"""
