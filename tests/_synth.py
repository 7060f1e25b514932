"""Test helpers: ONE small synthesis configuration shared by the renderer,
dataset and CLI tests, so that XLA compiles its two jitted calls once per session
(``ncjax synth --size 64x128 --batch 4`` builds exactly this configuration)."""

import functools

import jax

import ncjax

HEIGHT, WIDTH, BATCH = 64, 128, 4
CONFIG = ncjax.SynthConfig(room=ncjax.RoomConfig(world="mix", rc_range=(0.3, 1.0)), width=WIDTH, height=HEIGHT)
CLI_ARGS = ["--size", f"{HEIGHT}x{WIDTH}", "--batch", str(BATCH), "--world", "mix", "--rc", "0.3:1.0"]


@functools.cache
def batch(seed: int):
    """(scenes, renderings, labels) of BATCH random samples."""
    keys = jax.random.split(jax.random.key(seed), BATCH)
    return jax.device_get(ncjax.synthesize_batch(keys, CONFIG))


def render_scenes(scenes):
    """Render a batch of BATCH (modified) scenes with the shared compiled renderer."""
    from ncjax.synth.render import _batched_render

    return jax.device_get(_batched_render(CONFIG)(scenes))
