#!/usr/bin/env python3
"""Checks the book and the README after `mdbook build` (run by `make docs`).

    python3 tools/check_docs.py [--repo DIR] [--book DIR] [--report report.json]

- Every relative link and image of every book page and of README.md points to a file that exists,
  and a `#fragment` to an id that the built HTML page has (so anchors are checked against
  mdBook's own heading ids, not a guess of them).
- README.md stays a user's page: at most 300 lines, no commit hashes, dates or issue numbers.
- The reference pages name what they document: every key of a real report.json (top level, its
  sections, its tile records), every property of the metadata schema's element class, every crate
  of Cargo.toml's [dependencies].

Prints one line per problem and exits 1 if there is any. Standard library only.
"""

import argparse
import html.parser
import json
import os
import re
import sys

README_MAX_LINES = 300
LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
FENCE = re.compile(r"^\s*(```|~~~)")
INLINE_CODE = re.compile(r"`+[^`]*`+")
# A commit hash: 7 to 40 hex digits with at least one digit and one letter a-f.
HASH = re.compile(r"\b(?=[0-9a-f]*[0-9])(?=[0-9a-f]*[a-f])[0-9a-f]{7,40}\b")
DATE = re.compile(r"\b(19|20)\d\d-[01]\d-[0-3]\d\b")
ISSUE = re.compile(r"(?<![\w&/])#\d+\b|\bissues? \d+\b", re.IGNORECASE)


def prose_lines(text):
    """(line number, line) outside fenced code blocks."""
    fenced = False
    for n, line in enumerate(text.split("\n"), 1):
        if FENCE.match(line):
            fenced = not fenced
            continue
        if not fenced:
            yield n, line


def links(text):
    """(line number, target) of every markdown link and image outside code."""
    for n, line in prose_lines(text):
        for m in LINK.finditer(INLINE_CODE.sub("", line)):
            yield n, m.group(1)


class Ids(html.parser.HTMLParser):
    def __init__(self):
        super().__init__()
        self.ids = set()

    def handle_starttag(self, tag, attrs):
        for k, v in attrs:
            if k == "id" and v:
                self.ids.add(v)


def html_ids(path, cache={}):
    if path not in cache:
        p = Ids()
        with open(path, encoding="utf-8") as f:
            p.feed(f.read())
        cache[path] = p.ids
    return cache[path]


def check_links(md_path, src_dir, book_dir, problems):
    """Relative links of one markdown file: the file exists, the fragment is an id of its page."""
    with open(md_path, encoding="utf-8") as f:
        text = f.read()
    base = os.path.dirname(md_path)
    for n, target in links(text):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.IGNORECASE):  # http:, mailto:, ...
            continue
        path, _, fragment = target.partition("#")
        resolved = os.path.normpath(os.path.join(base, path)) if path else md_path
        where = f"{md_path}:{n}"
        if not os.path.exists(resolved):
            problems.append(f"{where}: link to {target}: {resolved} does not exist")
            continue
        if not fragment:
            continue
        if not resolved.endswith(".md"):
            problems.append(f"{where}: link to {target}: a fragment on a file that is not a page")
            continue
        rel = os.path.relpath(resolved, src_dir)
        if rel.startswith(".."):
            problems.append(f"{where}: link to {target}: a fragment into a page outside the book")
            continue
        page = os.path.join(book_dir, rel[:-3] + ".html")
        if not os.path.exists(page):
            problems.append(f"{where}: link to {target}: {page} was not built (not in SUMMARY.md?)")
        elif fragment not in html_ids(page):
            problems.append(f"{where}: link to {target}: no id '{fragment}' in {page}")


def check_readme(readme, problems):
    with open(readme, encoding="utf-8") as f:
        text = f.read()
    lines = text.split("\n")
    count = len(lines) - (1 if text.endswith("\n") else 0)
    if count > README_MAX_LINES:
        problems.append(f"{readme}: {count} lines, more than {README_MAX_LINES}: move detail into the book")
    for n, line in enumerate(lines, 1):
        for what, pattern in (("a commit hash", HASH), ("a date", DATE), ("an issue number", ISSUE)):
            m = pattern.search(line)
            if m:
                problems.append(f"{readme}:{n}: {what} ({m.group(0)}): the README carries no run history")


def documented(page, names, what, problems):
    """Every name appears on the page as inline code."""
    with open(page, encoding="utf-8") as f:
        codes = {c.strip("`") for c in INLINE_CODE.findall(f.read())}
    for name in sorted(set(names)):
        if name not in codes:
            problems.append(f"{page}: {what} `{name}` is not documented")


def report_keys(report):
    """The keys report.json readers rely on: top level, each section's, each tile record's."""
    keys = set(report)
    for value in report.values():
        if isinstance(value, dict):
            keys |= set(value)
        elif isinstance(value, list) and value and isinstance(value[0], dict):
            for item in value:
                keys |= set(item)
    return keys


def dependencies(cargo_toml):
    """Crate names of the [dependencies] table."""
    names, inside = [], False
    with open(cargo_toml, encoding="utf-8") as f:
        for line in f:
            s = line.strip()
            if s.startswith("["):
                inside = s == "[dependencies]"
            elif inside and re.match(r"^[A-Za-z0-9_-]+\s*=", s):
                names.append(s.split("=", 1)[0].strip())
    return names


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    ap.add_argument("--repo", default=here)
    ap.add_argument("--book", help="built HTML (default REPO/target/book)")
    ap.add_argument("--report", help="a report.json written by the current binary")
    a = ap.parse_args(argv)
    repo = a.repo
    src = os.path.join(repo, "docs", "src")
    book = a.book or os.path.join(repo, "target", "book")
    problems = []
    pages = []
    for root, _, files in os.walk(src):
        pages += [os.path.join(root, f) for f in files if f.endswith(".md")]
    for page in sorted(pages):
        check_links(page, src, book, problems)
    readme = os.path.join(repo, "README.md")
    check_links(readme, src, book, problems)
    check_readme(readme, problems)
    if a.report:
        with open(a.report, encoding="utf-8") as f:
            documented(os.path.join(src, "reference", "report-json.md"), report_keys(json.load(f)),
                       "report.json key", problems)
    with open(os.path.join(repo, "schemas", "bimtiles.schema.json"), encoding="utf-8") as f:
        schema = json.load(f)
    for cls in schema.get("classes", {}).values():
        documented(os.path.join(src, "reference", "metadata-schema.md"), cls.get("properties", {}),
                   "schema property", problems)
    index_schema = os.path.join(repo, "schemas", "element-index.schema.json")
    if os.path.exists(index_schema):
        with open(index_schema, encoding="utf-8") as f:
            index = json.load(f)["properties"]
        documented(os.path.join(src, "reference", "element-index.md"),
                   {**index, **index["dictionaries"]["properties"], **index["columns"]["properties"]},
                   "element index key", problems)
    documented(os.path.join(src, "design", "dependencies.md"),
               dependencies(os.path.join(repo, "Cargo.toml")), "dependency", problems)
    for p in problems:
        print(p)
    print(f"docs check: {len(pages) + 1} pages, {len(problems)} problem(s)")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
