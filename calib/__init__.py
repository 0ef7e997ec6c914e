"""Colour science for grassd: captures, colour correction, CIELAB/CIEDE2000, OGCD, length tables.

Never imports ``grassd.sim``, ``grassd.firmware_proto`` or ``grassd.daemon``. Conventions
(white points, Y of white = 1, Bradford adaptation, D50 CIELAB) live in
:mod:`grassd.calib.colour_spaces`. Errors derive from :class:`grassd.calib.errors.CalibError`.

API (main entry points; units in brackets)
-------------------------------------------
Colour spaces (``colour_spaces``)
    ``rec709_to_prophoto(rgb)``, ``prophoto_to_rec709(rgb)``, ``rec709_to_xyz``,
    ``prophoto_to_xyz``, ``xyz_to_lab(xyz)`` (D50 white), ``prophoto_to_lab(rgb)``,
    ``luminance(rgb, space)``; constants ``WHITE_D50_XYZ``, ``M_REC709_TO_PROPHOTO`` ...
Colour difference
    colour-science's ``colour.delta_E(lab1, lab2, method="CIE 2000")`` (CIEDE2000, Sharma,
    Wu & Dalal 2005); no copy of our own (:mod:`grassd.calib.ogcd` says why).
Exposure (``exposure``)
    ``normalise_exposure(rgb, grey_rgb, space="prophoto"|"rec709", white_balance=False)``
    -> linear RGB with the grey at Y = 0.18; ``exposure_matrix(grey_rgb, ...)`` -> (3, 3).
Charts and colour correction (``charts``, ``ccm``)
    ``get_chart("colorchecker-classic" | "spydercheckr-24" | path.csv)`` -> ``ReferenceChart``
    (``.lab`` D50, ``.prophoto()``); ``fit_ccm(virtual, real, method="3x3"|"root-polynomial"|
    "auto")`` -> ``ColourCorrection`` (``.matrix``, ``.apply(rgb)``, ``.residual_de00``,
    ``.mean_de00``, ``.max_de00``, leave-one-out ``.loo_de00``, ``.loo_mean_de00``,
    ``.loo_max_de00``, ``.reported_de00``, ``.form``, ``.candidates``); ``select_ccm(virtual,
    real)`` (the form of :data:`CCM_FORMS` of lowest leave-one-out mean dE00);
    ``compare_ccm_forms``, ``compare_ccm_methods(virtual, real)``.
Checker photos (``checker_photo``)
    ``checker_white_balance(raw, corners, chart)``, ``checker_photo_patches(raw, corners, chart,
    white_balance)`` -> (24, 3) ProPhoto, ``checker_clipping`` / ``refuse_clipped_checker``:
    every path raises ``ClippedCheckerError`` for patches clipped near the white level or at 0.
Cameras by spectral sensitivities (``camera_response``, ``spectral_virtual_camera``)
    ``read_sensitivities(csv)`` / ``CameraSensitivities.from_colour("nikon-d5100")`` [nm] ->
    ``.raw_rgb(reflectance, light)``, ``.rec709_map(light)`` -> ``CameraMap``;
    ``checker_experiment``, ``ccm_forms_on_checker``, ``camera_route_de00``;
    ``SpectralVirtualCamera(sensitivities, light)`` (non-negative response),
    ``spectral_checker_scene(camera)`` -> camera-RGB image for ``photograph_camera_rgb``.
A simulated pixel's camera RGB through spectra (``spectral_prediction``)
    ``sigmoid_spectra(albedo_linear)`` [0..1] -> (..., n) Jakob-Hanika reflectances;
    ``emitter_spectra(rgb)``, ``fitted_light_basis(texels, weights)`` -> (n, 3) light basis;
    ``transfer(monomial_spectra, sensitivities, basis)`` -> (M, 3, C);
    ``Development(sensitivities, multipliers, rgb_cam, grey_y).develop(raw)`` -> ProPhoto.
Captures (``raw``, ``regions``, ``dng``)
    ``develop_raw(path, white_balance="camera"|(r, g, b[, g2]))`` -> ``DevelopedRaw`` (``.rgb``
    (H, W, 3) float32 ProPhoto linear, negative components kept, ``.quad_mean(corners)``,
    ``.checker_patches(chart_corners)``); ``quad_mean(image, corners)`` [pixels (x, y)];
    ``extract_checker_patches(image, chart_corners)`` -> (24, 3);
    ``write_linear_dng(path, xyz, DngCamera(...), exposure=)`` / ``write_dng(path, raw, camera)``.
OGCD (``ogcd``)
    ``ogcd_from_lab(lab)``; ``ogcd_from_rgb(rgb, rgb_stderr=None, space="rec709", ccm=None)``
    -> ``OGCDResult(ogcd, ogcd_stderr, lab)`` (independent-error, conservative);
    ``ogcd_from_samples(rgb_samples (S, n, 3), ...)`` (correlation-aware).
Characteristics and tables (``characteristic``, ``length_table``)
    ``Characteristic(lengths_mm, ogcd, ogcd_stderr=None)`` [mm, dE00], ``.from_rgb(...)``,
    ``.from_lab(...)``; ``fit_characteristic(c)`` -> ``FittedCharacteristic`` (callable [mm ->
    dE00], ``.inverse(ogcd)`` [-> mm], ``.ogcd_range``);
    ``build_length_table(c)`` -> ``LengthTable`` (``.lengths_um`` (256,) uint16 [um],
    ``.r2_before``, ``.r2_after``, ``.ogcd_range``, ``.target_ogcd``, ``.achieved_ogcd``).
HDR brackets (``hdr_merge``, ``raw_bracket``)
    ``recover_response(shots_uint8, exposures)`` -> (256, 3) inverse response (Debevec-Malik);
    ``merge_ldr(shots, exposures, response)`` / ``merge_linear(shots, exposures)`` ->
    ``MergeResult`` (``.radiance`` relative linear, ``.clipped``, ``.black``);
    ``develop_bracket(dng_paths)`` -> linear Rec.709 shots with saturation marked.
Comparison (``compare``)
    ``discrete_frechet(p, q)``, ``frechet_characteristics(a, b)``, ``max_ogcd_error(a, b)``.
"""
