"""The rendering core: maps, the BRDF, the texel renderer and the rendering loss.

Nothing here reads files or draws training data; everything above builds on it.

* :mod:`~mi_svbrdf.core.maps` -- the ``(B, 10, H, W)`` map tensor: channel layout, names, checks;
* :mod:`~mi_svbrdf.core.brdf_torch` -- the BRDF in plain PyTorch (the reference);
* :mod:`~mi_svbrdf.core.render_drjit` -- the same BRDF as fused Dr.Jit kernels (``dr.wrap``);
* :mod:`~mi_svbrdf.core.render` -- the texel renderer (one shading point per texel) on both backends;
* :mod:`~mi_svbrdf.core.configurations` -- the loss's random light/view configurations;
* :mod:`~mi_svbrdf.core.ambient` -- ambient environments of many distant lights and their renderings;
* :mod:`~mi_svbrdf.core.loss` -- the rendering loss and the mixed loss;
* :mod:`~mi_svbrdf.core.flash` -- the authors' flash photo and 8-bit photo pipeline;
* :mod:`~mi_svbrdf.core.colour` -- the one photo gamma and luminance;
* :mod:`~mi_svbrdf.core.brdf_gltf`, :mod:`~mi_svbrdf.core.brdf_measured` -- the BRDF models beside ours (glTF's,
  measured tables); :mod:`~mi_svbrdf.core.conoscopic` -- comparing BRDFs on a conoscopic grid;
* :mod:`~mi_svbrdf.core.settings` -- dataclass configs from dicts, with field checks;
* :mod:`~mi_svbrdf.core.transforms` -- the networks' log input transform;
* :mod:`~mi_svbrdf.core.ssim`, :mod:`~mi_svbrdf.core.metrics` -- (MS-)SSIM and the evaluation metrics.

Start reading at :mod:`~mi_svbrdf.core.render`.
"""
