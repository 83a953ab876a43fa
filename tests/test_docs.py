"""The manual's examples run, so that they cannot go stale.

Pages: ``README.md``, every ``docs/**/*.md`` and ``scenarios/README.md``.  In each page:

- a fenced ``sh`` block's lines that start with ``graphcal `` are run with the installed
  ``graphcal`` script (the one beside ``sys.executable``) and must exit with status 0;
- a fenced ``python`` block is executed with ``exec``;
- a block whose fence has ``<!-- no-run -->`` on the line just above it is not run (for
  commands that need files the manual does not create, such as ASTERIX recordings, and for
  long Monte-Carlo runs);
- ``<!-- expect: TEXT -->`` lines right after a block's closing fence check its output: the
  output must contain TEXT, or, when TEXT ends with ``NUMBER ± TOLERANCE``, the first number
  after the label in the output must lie within the tolerance of NUMBER; ``<!-- expect:
  "TEXT" -->`` (in double quotes) always asks for TEXT as it stands, ``±`` included;
- a ``text`` block with ``<!-- output -->`` on the line just above it shows what the last run
  block printed: each of its lines other than ``...`` must be in that output;
- a block with ``<!-- file: NAME -->`` on the line just above it (a ``sites.toml`` the page
  shows) is written to NAME in the page's folder, so that the blocks after it use it;
- in the README's tour and the pages of ``PROSE_CHECKED``, every ``NUMBER ± NUMBER`` of the
  prose after a run block (up to the next run block) must be quoted, as printed, in one of
  that block's expect lines, so that the numbers the prose quotes are checked too.

The blocks of one page run in order in one temporary folder that links to the bundled
``scenarios/`` and ``models/``, so later blocks use what earlier ones wrote.  A page that uses
``demo-out`` without simulating it gets a copy of the demo network simulated with seed 1, as in
the README's tour.  Each page is one test, so the test processes (``make test`` runs one per
core) share the pages out and each page runs once.  In all comparisons runs of spaces and line
breaks count as one space.

Checks that need no run: every ``graphcal`` command line of every block, run or not
(synopses in ``text`` blocks included), names an existing command and only options that
command has; every ``graphcal.…`` name quoted in a code span imports; every module appears
in the API reference (docs/api/); lists and tables render as such; the README stays under
15 000 bytes (its HTML comment lines, the checks above, not counted) and its links resolve.
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import shlex
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from tests.paths import MODELS, ROOT, SCENARIOS

DOCS = ROOT / "docs"
PAGES = [ROOT / "README.md", *sorted(DOCS.rglob("*.md")), SCENARIOS / "README.md"]
GRAPHCAL = Path(sys.executable).with_name("graphcal")
DEMO_COMMAND = "graphcal simulate scenarios/demo_network.toml --out demo-out --seed 1"
COMMAND_TIMEOUT_S = 300

FENCE = re.compile(r"^(?P<indent>[ \t]*)(?P<fence>`{3,})(?P<lang>[\w+-]*)")
NO_RUN = "<!-- no-run -->"
OUTPUT = "<!-- output -->"
FILE = re.compile(r"^<!--\s*file:\s*(?P<name>[\w.-]+)\s*-->$")
EXPECT = re.compile(r"^\s*<!--\s*expect:\s*(?P<text>.*?)\s*-->\s*$")
NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
NUMBER_CHECK = re.compile(rf"^(?:(?P<label>.*?)\s+)?(?P<value>{NUMBER})\s*±\s*(?P<tol>{NUMBER})$")
PLUS_MINUS = re.compile(rf"(?<![\w.]){NUMBER}\s*±\s*{NUMBER}")
#: Pages whose prose numbers are checked against expect lines (the README's tour always is).
PROSE_CHECKED = ("docs/own-recording.md",)
TOUR = ("<!-- --8<-- [start:tour] -->", "<!-- --8<-- [end:tour] -->")


@dataclass
class Block:
    """One fenced code block of a page."""

    page: Path
    line: int  # 1-based line of the opening fence
    lang: str
    code: str
    run: bool
    expects: list[str] = field(default_factory=list)
    shows_output: bool = False  # a ``text`` block marked <!-- output -->
    file: str | None = None  # written to this name in the page's folder (<!-- file: NAME -->)
    end: int = 0  # 1-based line of the last expect line (or of the closing fence)

    @property
    def where(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.line}"

    def commands(self) -> list[str]:
        """The block's ``graphcal`` command lines (continuation lines joined)."""
        joined: list[str] = []
        pending = ""
        for raw in self.code.splitlines():
            line = pending + raw.strip()
            if line.endswith("\\"):
                pending = line[:-1] + " "
                continue
            pending = ""
            if line.startswith("graphcal "):
                joined.append(line)
        return joined


def read_blocks(page: Path) -> list[Block]:
    """Every fenced code block of a Markdown page, with its run flag and expectations."""
    lines = page.read_text(encoding="utf-8").splitlines()
    found: list[Block] = []
    i = 0
    while i < len(lines):
        opening = FENCE.match(lines[i])
        if not opening:
            i += 1
            continue
        start, fence, indent = i, opening["fence"], len(opening["indent"])
        body: list[str] = []
        i += 1
        while i < len(lines) and not (
            lines[i].strip().startswith(fence) and lines[i].strip().strip("`") == ""
        ):
            body.append(lines[i][indent:] if lines[i][:indent].strip() == "" else lines[i])
            i += 1
        expects: list[str] = []
        j = i + 1
        while j < len(lines) and (match := EXPECT.match(lines[j])):
            expects.append(match["text"])
            j += 1
        above = lines[start - 1].strip() if start > 0 else ""
        named = FILE.match(above)
        found.append(Block(page, start + 1, opening["lang"], "\n".join(body), above != NO_RUN,
                           expects, shows_output=above == OUTPUT, end=j,
                           file=named["name"] if named else None))
        i = j
    return found


def runnable(block: Block) -> bool:
    if not block.run or block.file is not None:
        return False
    if block.lang == "python":
        return True
    return block.lang == "sh" and bool(block.commands())


def check_expectations(block: Block, output: str) -> None:
    output = " ".join(output.split())  # runs of spaces and line breaks count as one space
    for text in (" ".join(expect.split()) for expect in block.expects):
        if len(text) > 1 and text[0] == text[-1] == '"':
            assert text[1:-1] in output, f"{block.where}: output lacks {text[1:-1]!r}:\n{output}"
            continue
        numeric = NUMBER_CHECK.match(text)
        if numeric is None:
            assert text in output, f"{block.where}: output lacks {text!r}:\n{output}"
            continue
        label = numeric["label"] or ""
        at = output.find(label)
        assert at >= 0, f"{block.where}: output lacks {label!r}:\n{output}"
        found = re.search(NUMBER, output[at + len(label):])
        assert found, f"{block.where}: no number after {label!r}:\n{output}"
        value, expected, tol = float(found[0]), float(numeric["value"]), float(numeric["tol"])
        assert abs(value - expected) <= tol, (
            f"{block.where}: {label} printed {value}, the page says {expected} ± {tol}"
        )


def check_shown_output(block: Block, output: str) -> None:
    """A ``<!-- output -->`` block's lines (``...`` skipped) are all in ``output``."""
    printed = " ".join(output.split())
    for line in block.code.splitlines():
        shown = " ".join(line.split())
        if shown and shown != "...":
            assert shown in printed, (
                f"{block.where}: the command does not print {shown!r}:\n{output}"
            )


def run_command(block: Block, command: str, cwd: Path) -> str:
    args = shlex.split(command, comments=True)
    env = {**os.environ, "COLUMNS": "160", "NO_COLOR": "1", "TERM": "dumb"}
    done = subprocess.run(
        [str(GRAPHCAL), *args[1:]], cwd=cwd, env=env, capture_output=True, text=True,
        timeout=COMMAND_TIMEOUT_S, check=False,
    )
    output = done.stdout + done.stderr
    assert done.returncode == 0, (
        f"{block.where}: `{command}` exited with {done.returncode}:\n{output}"
    )
    return output


def run_python(block: Block, namespace: dict[str, object], cwd: Path) -> str:
    buffer = io.StringIO()
    previous = Path.cwd()
    os.chdir(cwd)
    try:
        with contextlib.redirect_stdout(buffer):
            exec(compile(block.code, block.where, "exec"), namespace)  # noqa: S102
    finally:
        os.chdir(previous)
    return buffer.getvalue()


EXECUTED = {
    str(page.relative_to(ROOT)): page
    for page in PAGES
    if any(runnable(block) for block in read_blocks(page))
}


def simulate_demo(folder: Path) -> Path:
    """The README tour's demo network (seed 1) in ``folder/demo-out``."""
    (folder / "scenarios").symlink_to(SCENARIOS)
    subprocess.run(
        [str(GRAPHCAL), *shlex.split(DEMO_COMMAND)[1:]], cwd=folder, check=True,
        capture_output=True, timeout=COMMAND_TIMEOUT_S,
    )
    return folder / "demo-out"


def run_page(page: Path, folder: Path, demo_out: Path | None) -> None:
    """Run a page's blocks in order in ``folder``; raise on the first failure."""
    blocks = [block for block in read_blocks(page) if runnable(block)]
    folder.mkdir(parents=True)
    (folder / "scenarios").symlink_to(SCENARIOS)
    (folder / "models").symlink_to(MODELS)
    if uses_tour_demo(blocks):
        assert demo_out is not None
        shutil.copytree(demo_out, folder / "demo-out")
    namespace: dict[str, object] = {"__name__": "__docs__"}
    output = ""
    for block in read_blocks(page):
        if block.shows_output:
            check_shown_output(block, output)
        if block.file is not None:
            (folder / block.file).write_text(block.code + "\n", encoding="utf-8")
        if not runnable(block):
            continue
        if block.lang == "python":
            output = run_python(block, namespace, folder)
        else:
            output = "".join(run_command(block, c, folder) for c in block.commands())
        check_expectations(block, output)


def uses_tour_demo(blocks: list[Block]) -> bool:
    """Whether a page uses ``demo-out`` without simulating it itself."""
    makes_demo = any("--out demo-out" in command for b in blocks for command in b.commands())
    return not makes_demo and any("demo-out" in block.code for block in blocks)


@pytest.fixture(scope="session")
def tour_demo(tmp_path_factory: pytest.TempPathFactory) -> Path | None:
    """The README tour's ``demo-out``, simulated once per test process when some page uses
    it without simulating it itself."""
    pages = [[b for b in read_blocks(page) if runnable(b)] for page in EXECUTED.values()]
    if not any(uses_tour_demo(blocks) for blocks in pages):
        return None
    root = tmp_path_factory.mktemp("tour")
    return simulate_demo(root)


# One test per page, so that the test processes share the pages (``make test`` runs one per
# core) and each page runs once.
@pytest.mark.parametrize("name", sorted(EXECUTED))
def test_page_examples_run(name: str, tour_demo: Path | None, tmp_path: Path) -> None:
    run_page(EXECUTED[name], tmp_path / "page", tour_demo)


def _cli_options() -> dict[str, set[str]]:
    """Every command of the CLI and the option names it takes."""
    import typer

    from graphcal.cli.app import app

    group = typer.main.get_command(app)
    options: dict[str, set[str]] = {}
    for name, command in group.commands.items():  # type: ignore[attr-defined]
        names = {"--help"}
        for param in command.params:
            names.update(param.opts)
            names.update(param.secondary_opts)
        options[name] = names
    return options


def test_documented_commands_exist() -> None:
    """Every documented ``graphcal`` line names a real command and only its options."""
    options = _cli_options()
    problems = []
    for page in PAGES:
        for block in read_blocks(page):
            if block.lang not in ("sh", "text", ""):
                continue
            for command in block.commands():
                words = shlex.split(command.replace("|", " "), comments=True)
                if len(words) < 2 or words[1].startswith("-"):
                    continue
                known = options.get(words[1])
                if known is None:
                    problems.append(f"{block.where}: unknown command {words[1]!r}")
                    continue
                for word in words[2:]:
                    flag = word.strip("[]").split("=")[0]
                    if flag.startswith("--") and flag not in known:
                        problems.append(f"{block.where}: {words[1]} has no option {flag}")
    assert not problems, "\n".join(problems)


def test_api_reference_covers_every_module() -> None:
    """Each module of graphcal appears in a ``::: module`` block under docs/api/."""
    documented = set()
    for page in (DOCS / "api").glob("*.md"):
        documented.update(re.findall(r"^::: ([\w.]+)", page.read_text(), flags=re.MULTILINE))
    missing = []
    for path in sorted((ROOT / "graphcal").rglob("*.py")):
        module = ".".join(path.relative_to(ROOT).with_suffix("").parts)
        if path.name == "__main__.py":
            continue
        if path.name == "__init__.py":
            module = module.removesuffix(".__init__")
            if module != "graphcal" and not path.read_text().strip():
                continue
        if module not in documented:
            missing.append(module)
    assert not missing, f"modules missing from docs/api/: {missing}"


def test_documented_names_resolve() -> None:
    """Every ``graphcal.module.name`` the pages quote in code spans can be imported."""
    import importlib

    missing = []
    for page in PAGES:
        text = page.read_text(encoding="utf-8")
        for dotted in sorted(set(re.findall(r"`(graphcal(?:\.\w+)+)", text))):
            parts = dotted.split(".")
            for cut in range(len(parts), 0, -1):
                try:
                    target: object = importlib.import_module(".".join(parts[:cut]))
                except ImportError:
                    continue
                for name in parts[cut:]:
                    target = getattr(target, name, None)
                if target is None:
                    missing.append(f"{page.relative_to(ROOT)}: {dotted}")
                break
    assert not missing, "\n".join(missing)


def test_lists_and_tables_render() -> None:
    """No list or table of a page ends up as plain text in a paragraph (Python-Markdown's rules:
    a blank line before a list or table, four spaces per nesting level)."""
    markdown = pytest.importorskip("markdown")  # from the docs extra
    problems = []
    for page in [*PAGES[:-1], SCENARIOS / "README.md"]:
        if page.name == "CONTRACT.md":  # kept as it is; docs/hooks/github_lists.py adapts it
            continue
        text = re.sub(r"^::: .*(?:\n[ \t]+.*)*", "", page.read_text(encoding="utf-8"),
                      flags=re.MULTILINE)  # mkdocstrings blocks and their options
        html = markdown.markdown(text, extensions=["tables", "pymdownx.superfences"])
        html = re.sub(r"<pre.*?</pre>", "", html, flags=re.DOTALL)
        for body in re.findall(r"<(?:p|li)>(.*?)</(?:p|li)>", html, flags=re.DOTALL):
            if re.search(r"\n\s*(?:[-*]|\d+\.) |\n\|", body):
                problems.append(f"{page.relative_to(ROOT)}: {body[:80]!r}")
    assert not problems, "\n".join(problems)


def prose_after_blocks(page: Path) -> list[tuple[Block, int, str]]:
    """Each prose line (outside fences and comments) after a run block, with that block.

    The README counts only inside its tour.  A line belongs to the last run block above it.
    """
    lines = page.read_text(encoding="utf-8").splitlines()
    lo, hi = 0, len(lines)
    if page.name == "README.md":
        lo = next(i for i, line in enumerate(lines) if line.strip() == TOUR[0])
        hi = next(i for i, line in enumerate(lines) if line.strip() == TOUR[1])
    blocks = read_blocks(page)
    inside = set()
    for block in blocks:  # fence, body and expect lines
        inside.update(range(block.line - 1, block.end))
    owner: Block | None = None
    found = []
    starts = {block.line - 1: block for block in blocks}
    for i in range(len(lines)):
        if i in starts and runnable(starts[i]):
            owner = starts[i]
        if lo <= i < hi and i not in inside and owner is not None:
            if not lines[i].lstrip().startswith("<!--"):
                found.append((owner, i + 1, lines[i]))
    return found


@pytest.mark.parametrize("name", ["README.md", *PROSE_CHECKED])
def test_prose_numbers_are_checked(name: str) -> None:
    """Every ``value ± sigma`` the prose quotes is in an expect line of the block it describes,
    as printed: the prose cannot keep a number the commands no longer print."""
    problems = []
    for block, line, text in prose_after_blocks(ROOT / name):
        expects = " ".join(" ".join(e.split()) for e in block.expects)
        for quoted in PLUS_MINUS.findall(text):
            if " ".join(quoted.split()) not in expects:
                problems.append(f"{name}:{line}: {quoted!r} is in no expect line of the "
                                f"block at {block.where}")
    assert not problems, "\n".join(problems)


def test_readme_is_short_and_its_links_resolve() -> None:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    shown = "".join(line for line in text.splitlines(keepends=True)
                    if not re.fullmatch(r"\s*<!--.*-->\s*", line))
    assert len(shown.encode("utf-8")) < 15_000  # bytes, as `wc -c` counts, less the checks
    for target in re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", text):
        if "://" not in target:
            assert (ROOT / target).exists(), f"README links to missing {target}"
