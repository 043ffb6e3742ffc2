"""The training recipes ship as data (``mi_svbrdf/nets/recipes.toml``) and load to the values they had as code."""
from __future__ import annotations

from importlib import resources
from typing import Any

import pytest

from mi_svbrdf.nets import train as T

#: ``mi_svbrdf.nets.train.RECIPES`` as it was when the recipes were written in Python (value, type and order).
EXPECTED: dict[str, dict[str, Any]] = {
    'single': {
        'name': 'single_compact',
        'kind': 'single',
        'simulator': {'preset': 'single_flash'},
        'sizes': [[0, 128], [13300, 256]],
        'steps': 14000,
        'validate_every': 1000,
        'map_weight': 1.0,
    },
    'multi': {
        'name': 'multi_compact',
        'kind': 'multi',
        'simulator': {'preset': 'multiview', 'n_images': [1, 5], 'remap_roughness': True},
        'init': 'bundled:single',
        'sizes': [[0, 128]],
        'steps': 5016,
        'validate_every': 500,
        'map_weight': 1.0,
    },
    'multi-broad': {
        'name': 'multi_broad',
        'kind': 'multi',
        'simulator': {'preset': 'multiview', 'n_images': [1, 5], 'remap_roughness': True,
                      'normal_strength': [0.6, 2.0], 'specular_scale': [0.9, 1.4],
                      'capture': {'ambient_lights': 3, 'ambient_intensity': 0.35,
                                  'ambient_intensity_log_std': 0.45, 'ambient_min_elevation': 12.0}},
        'init': 'bundled:multi',
        'sizes': [[0, 128]],
        'steps': 5000,
        'lr': 5e-05,
        'warmup': 100,
        'validate_every': 500,
        'map_weight': 1.0,
    },
    'multi-spec': {
        'name': 'multi_spec',
        'kind': 'multi',
        'simulator': {'preset': 'multiview', 'n_images': [1, 5], 'remap_roughness': True, 'specular_scale': [0.9, 1.4]},
        'init': 'bundled:multi',
        'sizes': [[0, 128]],
        'steps': 5000,
        'lr': 5e-05,
        'warmup': 100,
        'validate_every': 500,
        'map_weight': 1.0,
    },
    'single-long': {
        'name': 'single_long',
        'kind': 'single',
        'simulator': {'preset': 'single_flash'},
        'init': 'bundled:single',
        'sizes': [[0, 128], [2500, 256]],
        'steps': 3000,
        'lr': 0.0001,
        'warmup': 100,
        'validate_every': 500,
        'map_weight': 1.0,
    },
    'single-render': {
        'name': 'single_render',
        'kind': 'single',
        'simulator': {'preset': 'single_flash'},
        'init': 'bundled:single',
        'sizes': [[0, 128], [1200, 256]],
        'steps': 1500,
        'lr': 5e-05,
        'warmup': 50,
        'validate_every': 500,
        'map_weight': 0.1,
    },
    'multi-render': {
        'name': 'multi_render',
        'kind': 'multi',
        'simulator': {'preset': 'multiview', 'n_images': [1, 5], 'remap_roughness': True},
        'init': 'bundled:multi',
        'sizes': [[0, 128]],
        'steps': 1500,
        'lr': 5e-05,
        'warmup': 50,
        'validate_every': 500,
        'map_weight': 0.1,
    },
    'multi-many': {
        'name': 'multi_many',
        'kind': 'multi',
        'simulator': {'preset': 'multiview', 'n_images': [1, 10], 'remap_roughness': True},
        'init': 'bundled:multi',
        'sizes': [[0, 128]],
        'steps': 3000,
        'lr': 5e-05,
        'warmup': 50,
        'validate_every': 500,
        'map_weight': 0.1,
    },
    'single-beckmann': {
        'name': 'single_beckmann',
        'kind': 'single',
        'simulator': {'preset': 'single_flash'},
        'init': 'bundled:single',
        'distribution': 'beckmann',
        'sizes': [[0, 128]],
        'steps': 400,
        'lr': 5e-05,
        'warmup': 50,
        'validate_every': 100,
        'map_weight': 0.0,
    },
    'full-single': {
        'name': 'single_full',
        'preset': 'full',
        'kind': 'single',
        'simulator': {'preset': 'single_flash'},
        'batch_size': 8,
        'lr': 2e-05,
        'betas': [0.9, 0.999],
        'steps': 400000,
        'warmup': 1000,
        'sizes': [[0, 256]],
        'validate_every': 5000,
        'val_size': 256,
        'checkpoint_every_s': 900.0,
    },
    'full-multi': {
        'name': 'multi_full',
        'preset': 'full',
        'kind': 'multi',
        'simulator': {'preset': 'multiview', 'n_images': [1, 5], 'remap_roughness': True},
        'batch_size': 2,
        'lr': 0.0002,
        'betas': [0.5, 0.999],
        'steps': 1000000,
        'warmup': 1000,
        'sizes': [[0, 256]],
        'validate_every': 10000,
        'val_size': 256,
        'checkpoint_every_s': 900.0,
    },
    'large': {
        'name': 'large_compact',
        'kind': 'large',
        'init': 'bundled:single',
        'simulator': {},
        'sizes': [[0, 128]],
        'steps': 5000,
        'lr': 0.0001,
        'warmup': 100,
        'validate_every': 500,
        'val_size': 128,
        'map_weight': 1.0,
        'ms_ssim_weight': 1.0,
    },
    'full-large': {
        'name': 'large_full',
        'preset': 'full',
        'kind': 'large',
        'simulator': {'material_size': 2048, 'crop': [512, 1024], 'exemplar_size': 256, 'pool_size': 8},
        'batch_size': 4,
        'lr': 0.0002,
        'betas': [0.5, 0.999],
        'steps': 400000,
        'warmup': 1000,
        'sizes': [[0, 512]],
        'validate_every': 10000,
        'val_size': 512,
        'checkpoint_every_s': 900.0,
        'map_weight': 1.0,
        'ms_ssim_weight': 1.0,
    },
    'multi-fused': {
        'name': 'multi_fused',
        'kind': 'multi',
        'net': {'fusion': True},
        'simulator': {'preset': 'multiview', 'n_images': [1, 6], 'remap_roughness': True},
        'alternate': [{}, {'flash_at_camera': True}],
        'init': 'bundled:multi',
        'base': 'bundled:single',
        'freeze': ['trunk.', 'fuse.', 'head.'],
        'batch_size': 4,
        'sizes': [[0, 256]],
        'steps': 1500,
        'lr': 0.0005,
        'warmup': 50,
        'validate_every': 250,
        'val_size': 256,
        'map_weight': 0.1,
    },
}


def _typed(value: Any) -> Any:
    """``value`` with each leaf paired with its type, so that 1 and 1.0 differ."""
    if isinstance(value, dict):
        return {k: _typed(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [type(value).__name__, [_typed(v) for v in value]]
    return (type(value).__name__, value)


def test_recipes_load_to_the_values_they_had_as_code() -> None:
    assert list(T.RECIPES) == list(EXPECTED)  # the order the CLI lists them in
    for name, recipe in EXPECTED.items():
        assert _typed(T.RECIPES[name]) == _typed(recipe), name


def test_every_recipe_has_a_one_line_description_and_builds_a_config() -> None:
    assert set(T.RECIPE_DESCRIPTIONS) == set(T.RECIPES)
    for name, text in T.RECIPE_DESCRIPTIONS.items():
        assert text.strip() and "\n" not in text, name
        cfg = T.load_config(name)
        assert cfg.name == EXPECTED[name]["name"] and cfg.kind == EXPECTED[name]["kind"]


def test_the_recipes_file_is_package_data() -> None:
    assert resources.files("mi_svbrdf.nets").joinpath(T.RECIPES_FILE).is_file()
    assert T.load_recipes() == T.RECIPES


def test_load_recipes_rejects_a_recipe_without_a_description(tmp_path) -> None:
    path = tmp_path / "r.toml"
    path.write_text('[a]\nname = "a"\n')
    with pytest.raises(ValueError, match="description"):
        T.load_recipes(path)


def test_the_training_guide_lists_every_recipe() -> None:
    from pathlib import Path

    guide = (Path(__file__).parents[1] / "docs" / "guides" / "training.md").read_text()
    assert [name for name in T.RECIPES if f"| `{name}` |" not in guide] == []
