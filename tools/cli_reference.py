"""Write docs/cli-reference.md: every ``sumo-ethics`` command with its full ``--help``, from click.

    python tools/cli_reference.py            # rewrite docs/cli-reference.md
    python tools/cli_reference.py --check    # exit 1 if the committed page is stale

The help is rendered at a fixed width (100 columns), so the page does not depend on the terminal;
tests/project/test_docs.py checks that the committed page is what this script writes.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import click

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "cli-reference.md"
WIDTH = 100

HEADER = """\
# CLI reference

Every `sumo-ethics` command with its options and defaults, exactly as `sumo-ethics COMMAND -h`
prints them. This page is generated from the command definitions by
`python tools/cli_reference.py` (a test checks that it is current); what the options do in
detail is explained on the [Running a scenario](usage.md), [Outputs](outputs.md),
[Explain and replay](explain.md), [Scenario suite](suite.md), [Sweeps](sweeps.md) and
[Trajectory prediction](prediction.md) pages.
"""


def _help(cmd: click.Command, path: list[str], parent: click.Context | None) -> tuple[str, click.Context]:
    # the command's own context settings (-h beside --help), as `sumo-ethics COMMAND -h` makes them; click
    # caches a command's help option on first use, so one made by a bare Context elsewhere in the same
    # process (a test) would otherwise print "--help" alone here
    cmd._help_option = None  # type: ignore[attr-defined]
    ctx = click.Context(cmd, info_name=path[-1], parent=parent, **{**cmd.context_settings, "terminal_width": WIDTH,
                                                                  "max_content_width": WIDTH})
    return ctx.get_help(), ctx


def _walk(cmd: click.Command, path: list[str], parent: click.Context | None, out: list[str]) -> None:
    text, ctx = _help(cmd, path, parent)
    level = "#" * min(len(path) + 1, 4)
    title = " ".join(path)
    out.append(f"\n{level} `{title}`\n\n```text\n{text.rstrip()}\n```\n")
    if isinstance(cmd, click.Group):
        for name in sorted(cmd.list_commands(ctx)):
            _walk(cmd.get_command(ctx, name), [*path, name], ctx, out)


def render() -> str:
    sys.path.insert(0, str(ROOT))
    from sumo_ethics.cli import cli

    out = [HEADER]
    _walk(cli, ["sumo-ethics"], None, out)
    return "".join(out)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="only check that the page is current")
    args = parser.parse_args()
    text = render()
    if args.check:
        if PAGE.read_text(encoding="utf-8") != text:
            print(f"{PAGE.relative_to(ROOT)} is stale: run python tools/cli_reference.py", file=sys.stderr)
            return 1
        return 0
    PAGE.write_text(text, encoding="utf-8")
    print(f"wrote {PAGE.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
