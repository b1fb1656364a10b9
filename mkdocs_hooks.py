"""MkDocs hook: a link to `files/NAME` (from a results page) or `results/files/NAME` names a raw result file in
experiments/results/, which the site does not copy; it becomes a link to that file in the repository (`repo_url`).
Pages link there directly; this keeps a page written with the short form building."""

import re

_FILES = re.compile(r"\]\((?:\.\./)*(?:results/)?files/([^)\s#]+)(#[^)\s]*)?\)")


def on_page_markdown(markdown, page, config, files):
    base = config["repo_url"].rstrip("/") + "/blob/main/experiments/results/"
    return _FILES.sub(lambda m: f"]({base}{m.group(1)}{m.group(2) or ''})", markdown)
