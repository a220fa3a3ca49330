"""`nuav2 bench exposure` on a short `hard` log: the solve brings the images closer to one exposure than
no correction, every variant is scored, and the table and CLI errors work."""

from __future__ import annotations

from nuav2.bench.exposure import VARIANTS, bench_exposure, markdown_table
from nuav2.cli import main as cli_main


def test_the_solve_beats_no_correction_on_a_short_hard_log(tmp_path) -> None:
    result = bench_exposure("hard", seconds=0.5, seed=3, sample=24, work_dir=tmp_path)
    v = result["variants"]
    assert set(v) == set(VARIANTS)
    assert all(x["images_scored"] >= 12 for x in v.values())
    assert v["shipped"]["error_rms_pct"] < 0.5 * v["none"]["error_rms_pct"]
    assert v["shipped"]["observations"] <= v["boxes left out"]["observations"]
    table = markdown_table(result, "nuav2 bench exposure")
    assert sum(line.startswith("| ") for line in table.splitlines()) == len(VARIANTS) + 1
    assert "nuav2 bench exposure" in table


def test_a_preset_without_exposure_effects_is_a_one_line_error(capsys) -> None:
    assert cli_main(["bench", "exposure", "--preset", "easy", "--seconds", "0.2"]) == 2
    err = capsys.readouterr().err.strip()
    assert "--preset easy" in err and len(err.splitlines()) == 1
    assert cli_main(["bench", "exposure", "--preset", "foggy"]) == 2
