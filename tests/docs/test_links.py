"""Every link and repository path in README.md and docs/ resolves inside the repository.

A clone is all a user has: a page that sends them to a file beside the checkout, or to one
that was renamed, leaves them with nothing. What is checked, outside fenced code blocks:

* Markdown links, ``[text](target)``, reference definitions (``[id]: target``) and HTML
  ``href``: an ``http``/``https``/``mailto`` target is allowed and not fetched; any other
  target is a path relative to the page, which must exist inside the repository root; an
  anchor (``page.md#heading``, ``#heading``) must name a heading of that page (as GitHub
  spells it) or an ``<a id>`` in it.
* Inline code that names a repository path: a word of a code span (an option's value after
  ``=``) that starts with ``../`` or ``./``, or holds a ``/`` and ends in a file extension of
  :data:`EXTENSIONS`, or ends with ``/`` under a top-level entry of the repository
  (``data/real/``). It must exist inside the root, taken from the root, from the page's
  folder or from the package folder ``gyrocal/`` (the architecture pages name modules by
  their path inside it); a ``../`` that leaves the root fails.

The skip rule: a code word is not a repository path, and is not checked, when it is

1. a URL (``scheme://...``) or a home path (``~/...``);
2. an absolute path: a file of the reader's machine (``/etc/slurm/slurm.conf``,
   ``/data/line3/devices.tsv``), except one beside the checkout (under the repository's
   parent folder, where a shared folder of the machine it was written on would be), which
   a clone does not have and which fails;
3. a template: it holds a placeholder (``<...>``, ``{...}``, ``*``, ``...``, ``…``, ``$``)
   or a component in capitals (``RUNS/``, ``DIR/``, as in the command synopses);
4. a run-time output: a path the repository's own ``.gitignore`` ignores (``results/``,
   ``reports/``, ``demo/``, ``.snakemake/``, ``paper/``), which runs write and a clone
   never holds.
"""

from __future__ import annotations

import fnmatch
import re
from functools import cache
from pathlib import Path
from urllib.parse import unquote

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "gyrocal"
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]

EXTENSIONS = {
    "md", "py", "pyi", "c", "h", "so", "yaml", "yml", "json", "toml", "cfg", "ini", "conf",
    "lock", "txt", "tsv", "csv", "parquet", "html", "j2", "ipynb", "svg", "png", "zip", "sh",
    "smk", "mcap", "db3", "gz", "bz2", "zst", "lz4",
}  # fmt: skip
ALLOWED_SCHEMES = ("http://", "https://", "mailto:")

_FENCE = re.compile(r"^\s{0,3}(```|~~~)")
_SPAN = re.compile(r"`([^`]+)`")
_LINK = re.compile(
    r"!?\[(?:[^\[\]]|\[[^\[\]]*\])*\]\(\s*<?([^()\s<>]*(?:\([^()\s]*\)[^()\s<>]*)*)>?(?:\s+\"[^\"]*\")?\s*\)"
)
_REF_DEF = re.compile(r"^\s{0,3}\[[^\]]+\]:\s*<?(\S+?)>?(?:\s|$)", re.M)
_HREF = re.compile(r"<a\s[^>]*href=\"([^\"]+)\"", re.I)
_ID = re.compile(r"<a\s[^>]*(?:id|name)=\"([^\"]+)\"", re.I)
_HEADING = re.compile(r"^\s{0,3}#{1,6}\s+(.*?)\s*#*\s*$", re.M)
_PLACEHOLDER = re.compile(r"[<>{}*$…]|\.\.\.")


def without_fences(text: str) -> str:
    """The page with every fenced code block's lines emptied (line numbers kept)."""
    out, fenced = [], False
    for line in text.split("\n"):
        if _FENCE.match(line):
            fenced = not fenced
            out.append("")
        else:
            out.append("" if fenced else line)
    return "\n".join(out)


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: its text, lower case, without punctuation, spaces as -."""
    text = re.sub(r"!?\[((?:[^\[\]]|\[[^\[\]]*\])*)\]\([^)]*\)", r"\1", heading)  # a link: its text
    text = re.sub(r"<[^>]+>", "", text).replace("`", "").lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(text: str) -> set[str]:
    """The anchors of a page: its headings' slugs (a repeated one numbered, as GitHub does)
    and its ``<a id>``s."""
    seen: dict[str, int] = {}
    out = set(_ID.findall(text))
    for heading in _HEADING.findall(without_fences(text)):
        base = slug(heading)
        n = seen.get(base, 0)
        seen[base] = n + 1
        out.add(base if n == 0 else f"{base}-{n}")
    return out


@cache
def _page_anchors(path: Path) -> set[str]:
    return anchors(path.read_text(encoding="utf-8"))


@cache
def _ignore_patterns(root: Path) -> tuple[str, ...]:
    gitignore = root / ".gitignore"
    if not gitignore.exists():
        return ()
    lines = (line.strip() for line in gitignore.read_text().splitlines())
    return tuple(line for line in lines if line and not line.startswith(("#", "!")))


def ignored(rel: str, root: Path = ROOT) -> bool:
    """Whether the repository's .gitignore ignores ``rel`` (a path from the root) or a folder
    it lies in: a pattern with a slash is matched from the root, one without at any level."""
    parts = [p for p in rel.strip("/").split("/") if p not in ("", ".")]
    for pattern in _ignore_patterns(root):
        anchored = "/" in pattern.rstrip("/")
        folder_only = pattern.endswith("/")
        glob = pattern.strip("/")
        for i in range(1, len(parts) + 1):
            if folder_only and i == len(parts) and not rel.endswith("/"):
                continue
            name = "/".join(parts[:i]) if anchored else parts[i - 1]
            if fnmatch.fnmatchcase(name, glob):
                return True
    return False


def _inside(path: Path, root: Path) -> bool:
    try:
        path.resolve().relative_to(root.resolve())
    except ValueError:
        return False
    return True


def _check_target(target: str, page: Path, root: Path, own: set[str]) -> str | None:
    """What is wrong with a link's target, or None (``own``: the page's anchors)."""
    if target.startswith(ALLOWED_SCHEMES):
        return None
    if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I):
        return "a link of another scheme than http(s) or mailto"
    path_part, _, anchor = target.partition("#")
    path_part = unquote(path_part.split("?")[0])
    if not path_part:  # an anchor of the page itself
        return None if unquote(anchor) in own else f"no heading or anchor #{anchor} on this page"
    dest = page.parent / path_part
    if not _inside(dest, root):
        return "leaves the repository"
    if not dest.exists():
        return "no such file in the repository"
    if anchor and dest.suffix == ".md" and unquote(anchor) not in _page_anchors(dest.resolve()):
        return f"no heading or anchor #{anchor} in {dest.resolve().relative_to(root.resolve())}"
    return None


def looks_like_path(word: str, root: Path = ROOT) -> bool:
    """Whether a code word names a repository path (the module docstring's rule)."""
    if "://" in word or word.startswith("~"):
        return False
    if word.startswith(("../", "./")):
        return True
    if "/" not in word:
        return False
    last = word.rstrip("/").rsplit("/", 1)[-1]
    if "." in last and last.rsplit(".", 1)[1].lower() in EXTENSIONS and not word.endswith("/"):
        return True
    return word.endswith("/") and (root / word.split("/", 1)[0]).exists()


def skipped(word: str, root: Path = ROOT) -> bool:
    """Whether a path-like code word is a template or a run-time output (the skip rule)."""
    if word.startswith("/"):
        beside = root.resolve().parent
        return beside == Path(beside.anchor) or not word.startswith(f"{beside.as_posix()}/")
    if _PLACEHOLDER.search(word):
        return True
    if any(part.isupper() for part in word.split("/") if part not in ("", ".", "..")):
        return True
    return not word.startswith("../") and ignored(word.removeprefix("./"), root)


def _check_path(word: str, page: Path, root: Path) -> str | None:
    """What is wrong with a path named in code, or None."""
    if word.startswith("/"):
        return "a path beside the checkout, which a clone does not have"
    bases = (
        [root, page.parent] if word.startswith(("../", "./")) else [root, page.parent, root / PACKAGE.name]
    )
    inside = [base / word for base in bases if _inside(base / word, root)]
    if not inside:
        return "leaves the repository"
    if not any(p.exists() for p in inside):
        return "no such file in the repository"
    return None


def check_page(text: str, page: Path, root: Path = ROOT) -> list[str]:
    """Every reference of a page (its text ``text``, at ``page``) that does not resolve
    inside ``root``, as "page:line: reference: why"."""
    body = without_fences(text)
    own = anchors(text)
    try:
        name = page.resolve().relative_to(root.resolve())
    except ValueError:
        name = page
    problems = []

    def report(pos: int, ref: str, why: str | None) -> None:
        if why:
            problems.append(f"{name}:{body.count(chr(10), 0, pos) + 1}: {ref}: {why}")

    for m in _SPAN.finditer(body):
        for word in m.group(1).split():
            word = word.rsplit("=", 1)[-1]
            word = word.strip("\"'(),;:")
            if looks_like_path(word, root) and not skipped(word, root):
                report(m.start(), word, _check_path(word, page, root))
    prose = _SPAN.sub(lambda m: " " * len(m.group(0)), body)  # a link is never inside code
    for pattern in (_LINK, _REF_DEF, _HREF):
        for m in pattern.finditer(prose):
            report(m.start(), m.group(1), _check_target(m.group(1), page, root, own))
    return problems


def test_every_reference_in_readme_and_docs_resolves():
    problems = [p for page in PAGES for p in check_page(page.read_text(encoding="utf-8"), page)]
    assert not problems, "\n".join(problems)


BESIDE = f"{ROOT.parent.as_posix()}/shared"  # a folder beside the checkout


def test_the_checker_finds_broken_references():
    """The checker on a page of its own: every broken reference is found, nothing else."""
    page = ROOT / "docs" / "synthetic.md"
    text = "\n".join(
        [
            "# A page",
            "## Its second heading",
            "[fine](method.md) [fine too](#its-second-heading) [web](https://example.org/x)",
            "[with anchor](log-format.md#3-the-manifest) [readme](../README.md)",
            "[broken](nope.md) [no heading](#nowhere) [outside](../../x.md)",
            "[bad anchor](method.md#no-such-heading)",
            "`docs/method.md` `gyrocal/io/log.py` `io/log.py` `python benchmarks/zoo/generator.py`",
            "`results/<batch>/calibration.json` `reports/index.html` `RUNS/fleet.parquet`",
            "`/etc/slurm/slurm.conf` `--config devices=/data/line3/devices.tsv` `accel_x/y/z` `m/s^2` `~/.aws/credentials` `s3://b/k.parquet`",
            f"`../shared/spec/log-format.md` `docs/nothing.md` `{BESIDE}/seeds/000.txt`",
            "```",
            "[inside a fence](ignored.md) `../ignored.md`",
            "```",
        ]
    )
    found = check_page(text, page)
    broken = [p.split(": ")[1] for p in found]
    assert broken == [
        "../shared/spec/log-format.md",
        "docs/nothing.md",
        f"{BESIDE}/seeds/000.txt",
        "nope.md",
        "#nowhere",
        "../../x.md",
        "method.md#no-such-heading",
    ], found
    assert found[0].startswith("docs/synthetic.md:10: ")
    assert "leaves the repository" in found[5]


def test_the_skip_rule():
    assert ignored("results/B1/U001/2026-01-05/calibration.json")
    assert ignored("reports/") and ignored(".snakemake/metadata") and ignored("demo/logs")
    assert ignored("benchmarks/.cache/throughput") and not ignored("benchmarks/zoo/README.md")
    assert not looks_like_path("gyrocal.calibration/1") and not looks_like_path("rad/s")
    assert looks_like_path("data/real/") and not looks_like_path("fit/")
    assert skipped("reports/<batch>/<device>/<session>.html") and skipped("FOLDER/analysis.zip")
    assert not skipped(f"{BESIDE}/spec/log-format.md") and not skipped("../shared/seeds/")
    assert skipped("/etc/slurm/slurm.conf") and skipped("/data/line3/devices.tsv")
