"""Files in and out: images, material folders, the thesis's strips, photos, calibrated photo sets.

* :mod:`~mi_svbrdf.io.atomic` -- write to a temporary name, then rename (the one atomic writer); strict JSON;
* :mod:`~mi_svbrdf.io.figures`, :mod:`~mi_svbrdf.io.tables` -- figures and contact sheets, Markdown tables;
* :mod:`~mi_svbrdf.io.image_io` -- PNG/EXR reading and writing with bit-depth and channel checks;
* :mod:`~mi_svbrdf.io.material_io` -- a material folder (four map images + ``material.json``), sRGB;
* :mod:`~mi_svbrdf.io.strip` -- the thesis dataset's PNG strips (panels side by side);
* :mod:`~mi_svbrdf.io.material_sets` -- a folder of strips and/or material folders as a dataset;
* :mod:`~mi_svbrdf.io.photos` -- reading user photos (EXIF orientation, crop, resize);
* :mod:`~mi_svbrdf.io.calibrated_photos` -- ``capture.json``: photos with their known cameras and lights;
* :mod:`~mi_svbrdf.io.export` -- a material as glTF 2.0, a Blender script or a Mitsuba scene;
* :mod:`~mi_svbrdf.io.viewer` -- the self-contained WebGL2 relighting page (``view.html``);
* :mod:`~mi_svbrdf.io.measured` -- measured-BRDF files (MERL ``.binary``, tabulated CSV).
"""
