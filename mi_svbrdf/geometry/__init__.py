"""From photos of a sample in a paper frame to a calibrated capture: the frame, homographies, cameras.

* :mod:`~mi_svbrdf.geometry.frame` -- the paper frame (:class:`~mi_svbrdf.geometry.frame.FrameSpec`)
  and finding its window's four corners in a photo, ordered and oriented;
* :mod:`~mi_svbrdf.geometry.homography` -- the plane-to-photo homography and the antialiased warp
  of a photo onto the sample plane;
* :mod:`~mi_svbrdf.geometry.poses` -- intrinsics (field of view, EXIF 35 mm focal length), the
  camera's pose from the corners (planar PnP) and the flash's position;
* :mod:`~mi_svbrdf.geometry.rectify` -- ``mi-svbrdf rectify``: reads the photos, runs the above on
  each and writes the rectified photos, ``rectify.json`` and ``capture.json``;
* :mod:`~mi_svbrdf.geometry.tags` -- the AprilTag print (:class:`~mi_svbrdf.geometry.tags.TagSheet`):
  its tags found in a photo, the camera calibrated from them, each photo's pose;
* :mod:`~mi_svbrdf.geometry.tag_rectify` -- ``mi-svbrdf rectify --frame tags``;
* :mod:`~mi_svbrdf.geometry.sheets` -- the printable sheets of both frames at true scale
  (``mi-svbrdf frame``).

The layer sits above :mod:`mi_svbrdf.io` (it reads photos and writes captures through it) and
below :mod:`mi_svbrdf.data` (the synthetic framed photos use its frame and camera conventions).
"""
