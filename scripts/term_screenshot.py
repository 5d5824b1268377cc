"""Run commands in a real 80-column terminal (tmux), capture the screen with its colours, and
render the capture to PNG (rich's SVG export, rasterised by headless chromium).

    python scripts/term_screenshot.py OUT.png --env K=V ... -- 'cmd 1' 'cmd 2'

Used for the before/after pictures in docs/img/. Needs tmux and chromium.
"""

from __future__ import annotations

import argparse
import shlex
import subprocess
import tempfile
import time
from pathlib import Path


def run_in_tmux(commands: list[str], env: dict[str, str], width: int, height: int) -> str:
    session = f"ppdshot{int(time.time() * 1000) % 100000}"
    exports = " ".join(f"{k}={shlex.quote(v)}" for k, v in env.items())
    shell = f"env {exports} PS1='$ ' TERM=xterm-256color bash --norc --noprofile"
    subprocess.run(["tmux", "new-session", "-d", "-s", session, "-x", str(width), "-y", str(height), shell],
                   check=True)  # fmt: skip
    try:
        subprocess.run(["tmux", "send-keys", "-t", session, "clear", "Enter"], check=True)
        time.sleep(0.5)
        for command in commands:
            typed = f"{command}; tmux wait -S {session}"
            subprocess.run(["tmux", "send-keys", "-t", session, typed, "Enter"], check=True)
            subprocess.run(["tmux", "wait", session], check=True, timeout=900)
        time.sleep(0.3)
        captured = subprocess.run(["tmux", "capture-pane", "-t", session, "-e", "-p"], check=True,
                                  capture_output=True, text=True).stdout  # fmt: skip
    finally:
        subprocess.run(["tmux", "kill-session", "-t", session], check=False)
    # the `; tmux wait -S ...` tail of each typed command is bookkeeping, not what a user types
    return captured.replace(f"; tmux wait -S {session}", "")


def render_png(ansi: str, out: Path, width: int, title: str) -> None:
    from rich.console import Console
    from rich.text import Text

    with open("/dev/null", "w") as sink:  # recorded, not shown
        console = Console(record=True, width=width, force_terminal=True, color_system="truecolor", file=sink)
        console.print(Text.from_ansi(ansi.rstrip("\n")), soft_wrap=True)
    svg = console.export_svg(title=title)
    with tempfile.TemporaryDirectory() as tmp:
        page = Path(tmp) / "shot.html"
        page.write_text(f"<html><body style='margin:0;background:#fff'>{svg}</body></html>")
        lines = ansi.rstrip("\n").count("\n") + 1
        size = f"{int(width * 12.2 + 60)},{int(lines * 24.4 + 110)}"
        subprocess.run(["chromium", "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
                        f"--window-size={size}", f"--screenshot={out.absolute()}", page.as_uri()],
                       check=True, capture_output=True, timeout=120)  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("out", type=Path)
    parser.add_argument("--env", action="append", default=[])
    parser.add_argument("--width", type=int, default=80)
    parser.add_argument("--height", type=int, default=30)
    parser.add_argument("--title", default="ppd")
    parser.add_argument("--ansi-out", type=Path)
    parser.add_argument("commands", nargs="+")
    args = parser.parse_args()
    env = dict(item.split("=", 1) for item in args.env)
    ansi = run_in_tmux(args.commands, env, args.width, args.height)
    if args.ansi_out:
        args.ansi_out.write_text(ansi)
    render_png(ansi, args.out, args.width, args.title)


if __name__ == "__main__":
    main()
