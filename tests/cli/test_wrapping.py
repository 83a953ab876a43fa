"""Free-text lines (warnings, notes, ``wrote ...``) wrap at the console width with a
hanging indent, at spaces only: no number, name or path is cut."""

from __future__ import annotations

import io

from rich.console import Console

from graphcal.cli.common import HANGING_INDENT, print_wrapped, wrap_words

WARNING = ("radar SUD: its residuals vary from aircraft to aircraft beyond the stated noise "
           "(a time-stamping bias fl-ls does not model, refraction, ADS-B along turns?): "
           "sigmas widened by up to 8.9 times over the formal ones (the per-aircraft spread); "
           "use --method graph, which models more; range_offset_m 5.2 ± 1.1 m over 1234.5 s")
PATH = "/a/very/long/folder/" + "x" * 90 + "/report.html"


def _printed(text: str, width: int, **kwargs) -> list[str]:
    out = Console(file=io.StringIO(), width=width, color_system=None, legacy_windows=False)
    print_wrapped(text, out, **kwargs)
    return out.file.getvalue().splitlines()  # type: ignore[attr-defined]


def test_wrapped_at_spaces_with_a_hanging_indent() -> None:
    lines = _printed(WARNING, 80, label="warning:", style="yellow")
    assert len(lines) > 2
    assert lines[0].startswith("warning: radar SUD:")
    assert all(line.startswith(" " * HANGING_INDENT) and line[HANGING_INDENT] != " "
               for line in lines[1:])
    assert max(len(line) for line in lines) <= 80
    assert " ".join(lines).split() == ["warning:", *WARNING.split()]


def test_numbers_stay_with_their_sigma_and_unit() -> None:
    for width in range(40, 100):
        text = "\n".join(wrap_words(WARNING, width))
        assert "5.2 ± 1.1 m" in text and "1234.5 s" in text, width


def test_a_long_path_stays_whole() -> None:
    lines = _printed(PATH, 80, label="wrote")
    assert lines == ["wrote", "  " + PATH]
    assert _printed("short.html", 80, label="wrote") == ["wrote short.html"]


def test_markup_is_printed_as_text() -> None:
    assert _printed("range [m] and [yellow]x[/yellow]", 80) == [
        "range [m] and [yellow]x[/yellow]"]
