"""The docs site's build (``mkdocs build --strict``; mkdocs.yml names this file as its hook).

Nothing here is a second copy of a page: every page is made at build time from its one source.

- Home: the repository's ``README.md``; the guide's overview page (``guide.md``): ``docs/README.md``
  (a ``README.md`` would otherwise be the site's home); the study: ``results/v2/VERDICT_RULES.md``,
  each edition's report, rules and figures (``results/v1/``); ``CHANGELOG.md``. Files outside ``docs/`` keep their
  repository path on the site, so the links to them hold.
- Relative links are written for the repository (``docs/game.md`` from the README,
  ``../results/REPORT.md`` from a guide page) and mapped onto the site's layout.
- API reference: one page per subpackage of ``dqn_transfer`` (and one for its top-level modules),
  rendered by mkdocstrings from the docstrings; :class:`SphinxRoles` turns the docstrings'
  ``:class:`...``` roles into links.
- Console scripts: one page per ``[project.scripts]`` entry of ``pyproject.toml``, holding its
  ``--help`` as printed when the site is built.
"""

from __future__ import annotations

import ast
import importlib
import json
import os
import posixpath
import re
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import griffe
from mkdocs.config.defaults import MkDocsConfig
from mkdocs.structure.files import File, Files
from mkdocs.structure.pages import Page

if sys.version_info >= (3, 11):
    import tomllib
else:  # mypy's own dependency there
    import tomli as tomllib

ROOT = Path(__file__).resolve().parent
PACKAGE = "dqn_transfer"
RESULTS = ROOT / "results"

# [text](target) and ![alt](target), not inside code spans (the docs' links never are)
LINK = re.compile(r"(\]\()([^)\s]+)(\))")


def subpackages() -> list[str]:
    """The package's subpackages (folders with an ``__init__.py``), by name."""
    return sorted(p.parent.name for p in (ROOT / PACKAGE).glob("*/__init__.py"))


def top_modules() -> list[str]:
    """The package's top-level modules (``dqn_transfer/*.py`` but ``__init__``), by name."""
    return sorted(p.stem for p in (ROOT / PACKAGE).glob("*.py") if p.stem != "__init__")


def console_scripts() -> dict[str, str]:
    """``[project.scripts]`` of pyproject.toml: script name -> ``module:function``."""
    with open(ROOT / "pyproject.toml", "rb") as file:
        return dict(tomllib.load(file)["project"]["scripts"])


def own_members(module: str) -> list[str]:
    """The public names a package's ``__init__.py`` defines itself (functions, classes, assignments), not
    those it imports."""
    tree = ast.parse((ROOT / module.replace(".", "/") / "__init__.py").read_text(encoding="utf-8"))
    names = []
    for node in tree.body:
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            names.append(node.name)
        elif isinstance(node, ast.Assign | ast.AnnAssign):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            names += [t.id for t in targets if isinstance(t, ast.Name)]
    return [name for name in names if not name.startswith("_")]


def reexports(module: str) -> list[str]:
    """``module.__all__``'s names defined elsewhere, each as a link to where it is documented (its
    defining module's section), or as plain code if it is not a class or function of the package."""
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))  # this checkout's package, even where another copy is installed
    package = importlib.import_module(module)
    own = set(own_members(module))
    links = []
    for name in getattr(package, "__all__", []):
        if name in own:
            continue
        obj = getattr(package, name)
        home = f"{getattr(obj, '__module__', '')}.{getattr(obj, '__qualname__', '')}"
        links.append(f"[`{name}`][{home}]" if home.startswith(PACKAGE + ".") else f"`{name}`")
    return links


def submodules(package: str) -> list[str]:
    """A subpackage's modules (``dqn_transfer/<package>/*.py`` but ``__init__``), by name."""
    return sorted(p.stem for p in (ROOT / PACKAGE / package).glob("*.py") if p.stem != "__init__")


def directive(name: str, heading_level: int, **options: object) -> list[str]:
    """A mkdocstrings ``:::`` block for ``name`` with these options (YAML, one line each)."""
    lines = [f"::: {name}", "    options:", f"      heading_level: {heading_level}"]
    lines += [f"      {key}: {json.dumps(value)}" for key, value in options.items()]
    return [*lines, ""]


def api_page(name: str) -> str:
    """One package's page: its docstring and what its ``__init__`` defines, the names it re-exports
    (linked to where they are documented, not documented twice), then each of its modules in full."""
    module = PACKAGE if name == PACKAGE else f"{PACKAGE}.{name}"
    children = top_modules() if name == PACKAGE else submodules(name)
    lines = directive(module, 1, show_submodules=False, members=False)
    links = reexports(module)
    if links:
        lines += [f"Importable from `{module}`: " + ", ".join(links) + ".", ""]
    for member in own_members(module):
        lines += directive(f"{module}.{member}", 2, show_root_full_path=False)
    for child in children:
        lines += directive(f"{module}.{child}", 2, show_submodules=False)
    return "\n".join(lines)


def help_texts() -> dict[str, str]:
    """Each console script's ``--help``, run in parallel, each in an empty working directory (Hydra's
    help writes nothing, but a run directory would land there if it did)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    env["COLUMNS"] = "100"  # argparse wraps to the terminal's width: the same page on every machine
    processes = {}
    with tempfile.TemporaryDirectory() as cwd:
        for script, target in console_scripts().items():
            module, function = target.split(":")
            code = f"import sys; sys.argv = [{script!r}, '--help']; from {module} import {function} as f; sys.exit(f())"
            processes[script] = subprocess.Popen(
                [sys.executable, "-c", code],
                cwd=cwd,
                env=env,
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
            )
        texts = {}
        for script, process in processes.items():
            out, err = process.communicate(timeout=300)
            if process.returncode != 0:
                raise RuntimeError(f"{script} --help exited with {process.returncode}:\n{err}")
            texts[script] = out
    return texts


def cli_page(script: str, target: str, text: str) -> str:
    return "\n".join(
        [
            "---",
            "hide: [toc]",  # the page is one wide block of text: give it the table of contents' width
            "---",
            "",
            f"# {script}",
            "",
            f"Entry point `{target}`. The text below is `{script} --help`, run when this site was built.",
            "",
            "```text",
            text.rstrip(),
            "```",
            "",
        ]
    )


def on_config(config: MkDocsConfig) -> MkDocsConfig:
    """The nav's generated sections: the API reference and the console scripts."""
    api = [{f"{PACKAGE} (top-level)": f"api/{PACKAGE}.md"}]
    api += [{f"{PACKAGE}.{name}": f"api/{name}.md"} for name in subpackages()]
    config.nav = [
        *(config.nav or []),
        {"Console scripts": [{script: f"cli/{script}.md"} for script in console_scripts()]},
        {"API reference": api},
    ]
    return config


def on_files(files: Files, config: MkDocsConfig) -> Files:
    overview = files.get_file_from_path("README.md")
    if overview is not None:  # docs/README.md: the guide's overview, not the home page
        files.remove(overview)
        files.append(File.generated(config, "guide.md", abs_src_path=overview.abs_src_path))
    files.append(File.generated(config, "index.md", abs_src_path=str(ROOT / "README.md")))
    files.append(File.generated(config, "CHANGELOG.md", abs_src_path=str(ROOT / "CHANGELOG.md")))
    for path in sorted(p for p in RESULTS.rglob("*") if p.suffix in (".md", ".png")):  # each edition's
        files.append(File.generated(config, f"results/{path.relative_to(RESULTS).as_posix()}", abs_src_path=str(path)))
    for name in [PACKAGE, *subpackages()]:
        files.append(File.generated(config, f"api/{name}.md", content=api_page(name)))
    scripts = console_scripts()
    for script, text in help_texts().items():
        files.append(File.generated(config, f"cli/{script}.md", content=cli_page(script, scripts[script], text)))
    return files


def site_path(page: Page, target: str, docs_dir: str) -> str | None:
    """Where ``target``, a relative link in ``page``'s source file, lands on the site (relative to the
    page), or None if it is not a link to map (a URL, an anchor in the page, or already right)."""
    if re.match(r"^[a-z][a-z0-9+.-]*:", target) or target.startswith(("#", "/")):
        return None
    path, _, anchor = target.partition("#")
    source = Path(page.file.abs_src_path or "").resolve()
    in_repo = posixpath.normpath(posixpath.join(source.parent.relative_to(ROOT).as_posix(), path))
    docs = Path(docs_dir).resolve().relative_to(ROOT).as_posix()
    on_site = in_repo[len(docs) + 1 :] if in_repo.startswith(docs + "/") else in_repo
    relative = posixpath.relpath(on_site, posixpath.dirname(page.file.src_uri) or ".")
    return relative + (f"#{anchor}" if anchor else "")


def on_page_markdown(markdown: str, page: Page, config: MkDocsConfig, files: Files) -> str:
    if page.file.abs_src_path is None:  # a generated page (API, console script): its links are the site's
        return markdown

    def remap(match: re.Match[str]) -> str:
        mapped = site_path(page, match.group(2), config.docs_dir)
        return match.group(0) if mapped is None else f"{match.group(1)}{mapped}{match.group(3)}"

    out, fenced = [], False
    for line in markdown.split("\n"):
        if line.lstrip().startswith("```"):
            fenced = not fenced
        out.append(line if fenced else LINK.sub(remap, line))
    return "\n".join(out)


ROLE = re.compile(r":(?:py:)?(class|func|meth|mod|attr|data|exc|obj):`(~?)([\w.]+)(?:\(\))?`")


class SphinxRoles(griffe.Extension):
    """The docstrings' Sphinx roles (``:class:`~dqn_transfer.agents.Learner```, ``:func:`require```) as
    links: the name is resolved in the docstring's scope, and an optional autoref links it if the site
    documents it (a private or external name then reads as plain code, without a warning)."""

    def on_package(self, *, pkg: griffe.Module, loader: griffe.GriffeLoader, **kwargs: Any) -> None:
        self._loader = loader
        self._walk(pkg)

    def _walk(self, obj: griffe.Object | griffe.Alias) -> None:
        if isinstance(obj, griffe.Alias):
            return
        if obj.docstring is not None:
            obj.docstring.value = ROLE.sub(lambda m: self._link(obj, m, self._loader), obj.docstring.value)
        for member in obj.members.values():
            self._walk(member)

    @staticmethod
    def _link(obj: griffe.Object, match: re.Match[str], loader: griffe.GriffeLoader) -> str:
        _, short, name = match.groups()
        shown = name.rsplit(".", 1)[-1] if short else name
        identifier = None
        if name.startswith(PACKAGE + "."):
            identifier = name
        else:
            scope: griffe.Object | None = obj
            while scope is not None and identifier is None:
                try:
                    identifier = scope.resolve(name)
                except Exception:  # griffe's NameResolutionError, or an alias it cannot follow
                    scope = scope.parent
        if identifier is None:
            return f"`{shown}`"
        try:  # a name a package re-exports is documented where it is defined
            target = loader.modules_collection[identifier]
            identifier = target.final_target.path if isinstance(target, griffe.Alias) else target.path
        except Exception:  # not loaded (another package's name) or an alias griffe cannot follow
            pass
        return f'<autoref identifier="{identifier}" optional><code>{shown}</code></autoref>'
