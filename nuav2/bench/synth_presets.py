"""The synthetic world's realism presets (``easy``, ``medium``, ``hard``) as the benchmarks use them.

Every image-quality benchmark runs per preset and reports the presets side by side. Until the
synthetic world offers the presets (``nuav2.synth.PRESETS`` and ``SynthConfig.for_preset``), only
``easy`` (today's world) exists, and asking for another names what is known.
"""

from __future__ import annotations


def known_presets() -> tuple[str, ...]:
    """The preset names the synthetic world offers (``("easy",)`` before the ladder lands)."""
    import nuav2.synth as synth

    return tuple(getattr(synth, "PRESETS", ("easy",)))


def parse_presets(text: str, flag: str = "--preset") -> list[str]:
    """``"easy,hard"`` or ``"all"`` -> preset names in the given order; unknown names are an error
    naming ``flag``."""
    known = known_presets()
    names = list(known) if text.strip() == "all" else [p.strip() for p in text.split(",") if p.strip()]
    bad = [p for p in names if p not in known]
    if bad or not names:
        raise ValueError(f"{flag}: unknown preset(s) {bad or [text]}; known: {', '.join(known)} (or all)")
    return list(dict.fromkeys(names))


def synth_config(preset: str, **overrides):
    """``SynthConfig`` of ``preset`` with ``overrides`` (fields such as ``seconds``, ``image_scale``)."""
    from nuav2.synth import SynthConfig

    parse_presets(preset)
    if hasattr(SynthConfig, "for_preset"):
        return SynthConfig.for_preset(preset, **overrides)
    return SynthConfig(**overrides)
