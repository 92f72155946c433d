"""MkDocs hooks: the study-file key reference generated from the schema, and the committed
results' pictures served from ``results/`` (the pages link them as ``results/<fig>/<fig>.png``;
nothing is copied into ``docs/``)."""

from __future__ import annotations

from pathlib import Path

from mkdocs.structure.files import File

ROOT = Path(__file__).resolve().parents[1]
MARKER = "<!-- schema-reference -->"
SHOWN = (".png", ".mp4")


def on_files(files, config):
    """Add the committed results' pictures and videos (not the scratch ``results/quick``)."""
    for path in sorted((ROOT / "results").rglob("*")):
        relative = path.relative_to(ROOT)
        if path.suffix in SHOWN and "quick" not in relative.parts and ".runs" not in relative.parts:
            files.append(
                File(
                    relative.as_posix(),
                    src_dir=str(ROOT),
                    dest_dir=config["site_dir"],
                    use_directory_urls=config["use_directory_urls"],
                )
            )
    return files


def on_page_markdown(markdown, page, config, files):
    """Replace the marker on the study-file page with the schema's own reference."""
    if MARKER not in markdown:
        return markdown
    from corrections_sim.study.key_reference import reference_markdown

    return markdown.replace(MARKER, reference_markdown())
