"""The documentation tools on their own: the benchmarks page writer (tools/bench_page.py) and the
book's checker (tools/check_docs.py), each on a small tree made here, so a change to either is
tested without a `make bench` run or a real book.

    python3 -m pytest tests/python/test_docs_tools.py
"""

import importlib.util
import json
import pathlib

REPO = pathlib.Path(__file__).resolve().parents[2]


def _load(name):
    spec = importlib.util.spec_from_file_location(name, REPO / "tools" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


bench_page = _load("bench_page")
check_docs = _load("check_docs")


def test_bench_page_replaces_only_its_section(tmp_path):
    page = tmp_path / "benchmarks.md"
    hand_kept = "## Hand-kept\n\n| model | s |\n|---|---|\n| duplex | 1.0 |\n"
    page.write_text(f"# Benchmarks\n\nIntro.\n\n{bench_page.BEGIN}\nold run\n{bench_page.END}\n\n{hand_kept}")
    out = tmp_path / "tiler.txt"
    out.write_text("model  triangles\nsample 12580\n")
    args = [str(page), "--run", "cargo run --example bench_tiler", str(out),
            "--date", "DATE", "--commit", "COMMIT", "--machine", "MACHINE"]
    assert bench_page.main(args) == 0
    text = page.read_text()
    assert "old run" not in text
    assert text.startswith("# Benchmarks\n\nIntro.\n\n")
    assert text.endswith(hand_kept)
    for expected in ("- date: DATE", "- commit: COMMIT", "- machine: MACHINE",
                     "```sh\ncargo run --example bench_tiler\n```", "sample 12580\n```"):
        assert expected in text
    # A second run replaces the first: one generated section.
    assert bench_page.main(args) == 0
    assert page.read_text() == text


def test_bench_page_adds_a_missing_section_after_the_title(tmp_path):
    page = tmp_path / "benchmarks.md"
    page.write_text("# Benchmarks\n\nHand-kept.\n")
    out = tmp_path / "t.txt"
    out.write_text("x\n")
    bench_page.main([str(page), "--run", "c", str(out), "--date", "D", "--commit", "C", "--machine", "M"])
    text = page.read_text()
    assert text.index(bench_page.BEGIN) < text.index("Hand-kept.")
    assert text.startswith("# Benchmarks\n")


def test_machine_reads_cpu_and_memory(tmp_path):
    cpu = tmp_path / "cpuinfo"
    cpu.write_text("processor\t: 0\nmodel name\t: Test CPU 3000\n")
    mem = tmp_path / "meminfo"
    mem.write_text("MemTotal:       25165824 kB\n")
    line = bench_page.machine(str(cpu), str(mem))
    assert line.startswith("Test CPU 3000, ")
    assert line.endswith(" cores, 24.0 GiB")


def _book(tmp_path, page_text, readme_text="# r\n"):
    """A minimal repository: one page and its built HTML, the schema and Cargo.toml."""
    src = tmp_path / "docs" / "src"
    (src / "reference").mkdir(parents=True)
    (src / "design").mkdir()
    (src / "page.md").write_text(page_text)
    (src / "other.md").write_text("# Other\n\n## A section\n")
    (src / "reference" / "report-json.md").write_text("`tool` `input` `files`\n")
    (src / "reference" / "metadata-schema.md").write_text("`id`\n")
    (src / "design" / "dependencies.md").write_text("`serde`\n")
    book = tmp_path / "target" / "book"
    book.mkdir(parents=True)
    (book / "other.html").write_text('<h1 id="other">Other</h1><h2 id="a-section">A section</h2>')
    (tmp_path / "README.md").write_text(readme_text)
    (tmp_path / "schemas").mkdir()
    (tmp_path / "schemas" / "bimtiles.schema.json").write_text(
        json.dumps({"classes": {"element": {"properties": {"id": {}}}}}))
    (tmp_path / "Cargo.toml").write_text('[package]\nname = "x"\n\n[dependencies]\nserde = "1"\n')
    report = tmp_path / "report.json"
    report.write_text(json.dumps({"tool": "t", "input": {"files": []}}))
    return ["--repo", str(tmp_path), "--report", str(report)]


def test_check_docs_passes_a_good_book(tmp_path, capsys):
    args = _book(tmp_path, "# P\n\n[o](other.md) [s](other.md#a-section) [w](https://example.org)\n"
                 "```sh\n[not a link](missing.md)\n```\n`[code](missing.md)`\n")
    assert check_docs.main(args) == 0, capsys.readouterr().out


def test_check_docs_finds_broken_links_and_anchors(tmp_path, capsys):
    args = _book(tmp_path, "# P\n\n[gone](gone.md) [bad anchor](other.md#no-such-heading)\n")
    assert check_docs.main(args) == 1
    out = capsys.readouterr().out
    assert "gone.md does not exist" in out
    assert "no id 'no-such-heading'" in out


def test_check_docs_holds_the_readme_to_its_rules(tmp_path, capsys):
    long_readme = "# r\n" + "line\n" * 300 + "Measured on 2026-11-27 at 6cd1739 (see #12).\n"
    args = _book(tmp_path, "# P\n", long_readme)
    assert check_docs.main(args) == 1
    out = capsys.readouterr().out
    assert "more than 300" in out
    assert "a commit hash (6cd1739)" in out
    assert "a date (2026-11-27)" in out
    assert "an issue number (#12)" in out


def test_check_docs_wants_every_report_key_schema_property_and_dependency(tmp_path, capsys):
    args = _book(tmp_path, "# P\n")
    (tmp_path / "report.json").write_text(json.dumps({"tool": "t", "input": {"files": [], "bytes": 1},
                                                      "undocumented": 1}))
    (tmp_path / "Cargo.toml").write_text('[dependencies]\nserde = "1"\nrayon = "1"\n[dev-dependencies]\nx = "1"\n')
    assert check_docs.main(args) == 1
    out = capsys.readouterr().out
    assert "report.json key `bytes`" in out
    assert "report.json key `undocumented`" in out
    assert "dependency `rayon`" in out
    assert "dependency `x`" not in out
