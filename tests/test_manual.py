"""The manual builds: ``mkdocs build --strict`` offline, every page of the nav present, no
broken link or anchor, no docstring warning, and the generated reference complete (every
command, every option of ``lightsim simulate``, every shipped rule set).

Skipped only where the documentation tools (``pip install -e .[docs]``) are missing.
"""

from __future__ import annotations

import html
import os
import re
import subprocess
import sys
from pathlib import Path

import click
import pytest

from lightsim.cli.main import cli
from lightsim.luminaires.regulations.ruleset import BUILTIN_DIR

for _tool in ("mkdocs", "material", "mkdocstrings", "mkdocstrings_handlers.python"):
    pytest.importorskip(_tool, reason=f"the manual's build needs {_tool} (extra 'docs')")

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "mkdocs.yml"
BUILD_SECONDS = 300


def _nav_pages() -> list[str]:
    """Every page file named in mkdocs.yml's nav."""
    text = CONFIG.read_text(encoding="utf-8")
    nav = re.split(r"(?m)^nav:", text, maxsplit=1)[1]
    return re.findall(r"([\w./-]+\.md)\s*$", nav, flags=re.M)


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The manual built with ``--strict`` into a temporary folder (fails with the log)."""
    out = tmp_path_factory.mktemp("site")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    run = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-f", str(CONFIG),
                          "-d", str(out)], cwd=ROOT, env=env, capture_output=True, text=True,
                         timeout=BUILD_SECONDS)
    if run.returncode != 0:
        problems = [ln for ln in run.stderr.splitlines() if ln.startswith(("WARNING", "ERROR"))]
        pytest.fail("mkdocs build --strict failed:\n" + "\n".join(problems or
                                                                 [run.stderr[-4000:]]))
    return out


def _text(page: Path) -> str:
    """A built page's visible text, tags removed."""
    body = page.read_text(encoding="utf-8")
    return html.unescape(re.sub(r"<[^>]+>", " ", body))


def _commands() -> dict[str, click.Command]:
    """Every command of the click tree by full name (``lightsim bench tracer``)."""
    found = {}

    def walk(cmd: click.Command, ctx: click.Context) -> None:
        found[ctx.command_path] = cmd
        if isinstance(cmd, click.Group):
            for name in cmd.list_commands(ctx):
                sub = cmd.get_command(ctx, name)
                if sub is not None and not sub.hidden:
                    walk(sub, click.Context(sub, info_name=name, parent=ctx))

    walk(cli, click.Context(cli, info_name="lightsim"))
    return found


def test_every_nav_page_exists():
    missing = [p for p in _nav_pages() if not (ROOT / "docs" / p).is_file()]
    assert not missing, f"pages in mkdocs.yml's nav without a file in docs/: {missing}"


def test_the_manual_builds_strict(site: Path):
    # --strict turns broken links and anchors, missing nav pages and docstring warnings
    # into a failed build (the fixture fails with the log); every nav page is written
    for page in _nav_pages():
        stem = page[:-3]
        built = stem + (".html" if stem == "index" or stem.endswith("/index") else "/index.html")
        assert (site / built).is_file(), f"{page} was not built"


def test_commands_page_has_every_command_and_option(site: Path):
    page = (site / "reference" / "commands" / "index.html").read_text(encoding="utf-8")
    headings = {html.unescape(re.sub(r"<[^>]+>", "", h)).replace("¶", "").strip()
                for h in re.findall(r"<h[23][^>]*>(.*?)</h[23]>", page, flags=re.S)}
    commands = _commands()
    assert not set(commands) - headings, f"commands missing: {set(commands) - headings}"
    # every option of `lightsim simulate`, in its own section (up to the next heading)
    start = page.index('id="lightsim-simulate"')
    section = page[start:page.find("<h2", start)]
    section = html.unescape(re.sub(r"<[^>]+>", " ", section))
    flags = [f for p in commands["lightsim simulate"].params if isinstance(p, click.Option)
             and not p.hidden for f in (*p.opts, *p.secondary_opts)]
    missing = [f for f in flags if not re.search(rf"(?<![\w-]){re.escape(f)}(?![\w-])", section)]
    assert not missing, f"options of lightsim simulate missing from the page: {missing}"
    assert len(flags) > 40


def test_rulesets_page_has_every_shipped_rule_set(site: Path):
    text = _text(site / "reference" / "rulesets" / "index.html")
    ids = sorted(p.stem for p in BUILTIN_DIR.glob("*.toml"))
    assert ids and not [i for i in ids if i not in text]
    assert "less sure" in text and "candela" in text
