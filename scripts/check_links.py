#!/usr/bin/env python3
"""Check that every relative link of the workspace's Markdown resolves.

Files checked: README.md, ARCHITECTURE.md, docs/*.md and crates/*/README.md (paths relative
to the repository root, which is this script's parent folder's parent). For every inline
link or image `[text](target)`, reference definition `[label]: target` and HTML
`href="…"`/`src="…"` outside code (fenced blocks, indented blocks and `code spans` are
skipped):

- an absolute URL (`https:`, `mailto:`, …) is not checked;
- a path must name an existing file or folder, relative to the linking file (a leading
  `/` means the repository root);
- a `#anchor` (alone, or after a path to a Markdown file) must be the GitHub slug of a
  heading of that file: lowercased, every character that is not a letter, digit, mark,
  `_`, `-` or space removed, spaces turned into `-`, a repeated slug suffixed `-1`, `-2`, …
  Explicit `<a name="…">`/`id="…"` anchors count too.

Python 3.11, standard library only. Prints each broken link as `file:line: target: why`
and exits 1 when there is one, 0 otherwise.

    python3 scripts/check_links.py [ROOT]
"""

from __future__ import annotations

import re
import sys
import unicodedata
from pathlib import Path
from urllib.parse import unquote

FENCE = re.compile(r"^ {0,3}(`{3,}|~{3,})")
INLINE_LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\[\]]*\])*\]\(\s*(<[^>]*>|[^)\s]+)(?:\s+(?:\"[^\"]*\"|'[^']*'|\([^)]*\)))?\s*\)")
REF_DEF = re.compile(r"^ {0,3}\[[^\]]+\]:\s*(<[^>]*>|\S+)")
HTML_ATTR = re.compile(r"""<[a-zA-Z][^>]*?\s(?:href|src)\s*=\s*["']([^"']+)["']""")
HTML_ANCHOR = re.compile(r"""<[a-zA-Z][^>]*?\s(?:name|id)\s*=\s*["']([^"']+)["']""")
CODE_SPAN = re.compile(r"(`+)(.+?)\1")
HEADING_ATX = re.compile(r"^ {0,3}(#{1,6})(?:[ \t]+(.*?))?(?:[ \t]+#+)?[ \t]*$")
SETEXT = re.compile(r"^ {0,3}(=+|-+)[ \t]*$")
SCHEME = re.compile(r"^[a-zA-Z][a-zA-Z0-9+.-]*:")


def markdown_files(root: Path) -> list[Path]:
    files = [root / "README.md", root / "ARCHITECTURE.md"]
    files += sorted((root / "docs").glob("*.md"))
    files += sorted((root / "crates").glob("*/README.md"))
    return [f for f in files if f.is_file()]


def prose_lines(text: str):
    """(line number, line) of the lines outside fenced and indented code blocks."""
    fence = None
    previous_blank = True
    for number, line in enumerate(text.splitlines(), start=1):
        m = FENCE.match(line)
        if fence is None and m:
            fence = m.group(1)[0] * len(m.group(1))
            continue
        if fence is not None:
            if line.strip().startswith(fence) and set(line.strip()) <= {fence[0]}:
                fence = None
            continue
        indented = line.startswith("    ") or line.startswith("\t")
        if indented and previous_blank and line.strip():
            # An indented code block (only after a blank line; list continuations
            # follow a non-blank line and stay prose).
            continue
        previous_blank = not line.strip()
        yield number, line


def inline_text(s: str) -> str:
    """A heading's text as GitHub renders it: code spans, links, images, emphasis and
    HTML tags reduced to their text."""
    s = CODE_SPAN.sub(lambda m: m.group(2).strip(), s)
    s = re.sub(r"!\[([^\]]*)\]\([^)]*\)", r"\1", s)
    s = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", s)
    s = re.sub(r"<[^>]+>", "", s)
    s = s.replace("*", "")
    return s


def slug(text: str) -> str:
    out = []
    for ch in inline_text(text).strip().lower():
        cat = unicodedata.category(ch)
        if ch == " ":
            out.append("-")
        elif ch in "-_" or cat[0] in "LMN" or cat == "Pc":
            out.append(ch)
    return "".join(out)


def anchors(path: Path, cache: dict[Path, set[str]]) -> set[str]:
    if path in cache:
        return cache[path]
    text = path.read_text(encoding="utf-8")
    seen: dict[str, int] = {}
    found: set[str] = set()
    previous = None
    for _, line in prose_lines(text):
        heading = None
        m = HEADING_ATX.match(line)
        if m:
            heading = m.group(2) or ""
        elif previous is not None and previous.strip() and SETEXT.match(line) and not previous.lstrip().startswith(("-", "*", ">", "|")):
            heading = previous.strip()
        if heading is not None:
            base = slug(heading)
            n = seen.get(base, 0)
            found.add(base if n == 0 else f"{base}-{n}")
            seen[base] = n + 1
        for a in HTML_ANCHOR.findall(line):
            found.add(a)
        previous = line
    cache[path] = found
    return found


def targets(line: str):
    """The link targets of one prose line, code spans removed."""
    line = CODE_SPAN.sub(lambda m: " " * len(m.group(0)), line)
    for m in INLINE_LINK.finditer(line):
        yield m.group(1).strip("<>")
    m = REF_DEF.match(line)
    if m:
        yield m.group(1).strip("<>")
    for t in HTML_ATTR.findall(line):
        yield t


def check(root: Path) -> list[str]:
    broken = []
    cache: dict[Path, set[str]] = {}
    for md in markdown_files(root):
        text = md.read_text(encoding="utf-8")
        rel_md = md.relative_to(root)
        for number, line in prose_lines(text):
            for target in targets(line):
                if SCHEME.match(target) or target.startswith("//"):
                    continue
                path_part, _, anchor = target.partition("#")
                path_part = unquote(path_part)
                anchor = unquote(anchor)
                if path_part:
                    base = root if path_part.startswith("/") else md.parent
                    dest = (base / path_part.lstrip("/")).resolve()
                    try:
                        dest.relative_to(root.resolve())
                    except ValueError:
                        broken.append(f"{rel_md}:{number}: {target}: outside the repository")
                        continue
                    if not dest.exists():
                        broken.append(f"{rel_md}:{number}: {target}: no such file or folder")
                        continue
                else:
                    dest = md
                if anchor and dest.is_file() and dest.suffix.lower() == ".md":
                    if anchor not in anchors(dest, cache):
                        broken.append(f"{rel_md}:{number}: {target}: no heading with anchor #{anchor} in {dest.relative_to(root.resolve()) if dest.is_absolute() else dest}")
    return broken


def main() -> int:
    root = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parent.parent
    root = root.resolve()
    files = markdown_files(root)
    broken = check(root)
    for b in broken:
        print(b)
    if broken:
        print(f"{len(broken)} broken link(s) in {len(files)} file(s)", file=sys.stderr)
        return 1
    print(f"all relative links resolve ({len(files)} files)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
