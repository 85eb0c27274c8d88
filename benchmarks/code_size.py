"""Count long files (>400 lines) and long functions (>60 lines) in a tree.

Usage: python benchmarks/code_size.py [TREE]   (default: this checkout)
Groups: vdsbi/ (library) and experiments/ + benchmarks/.
Lines of a file: number of lines (as `wc -l` on text ending in newline).
Function length: end_lineno - lineno + 1 of the def (decorators excluded,
docstring included); nested functions and methods are counted on their own.
"""

import ast
import os
import sys

FILE_LIMIT = 400
FUNC_LIMIT = 60
GROUPS = {"vdsbi": ["vdsbi"], "experiments+benchmarks": ["experiments", "benchmarks"]}


def py_files(tree, dirs):
    for d in dirs:
        for root, subdirs, files in os.walk(os.path.join(tree, d)):
            subdirs[:] = sorted(s for s in subdirs if s != "__pycache__")
            for f in sorted(files):
                if f.endswith(".py"):
                    yield os.path.join(root, f)


def qualnames(node, prefix=""):
    for child in ast.iter_child_nodes(node):
        if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
            name = prefix + child.name
            yield name, child.end_lineno - child.lineno + 1
            yield from qualnames(child, name + ".")
        elif isinstance(child, ast.ClassDef):
            yield from qualnames(child, prefix + child.name + ".")
        else:
            yield from qualnames(child, prefix)


def main(tree):
    for group, dirs in GROUPS.items():
        long_files, long_funcs = [], []
        for path in py_files(tree, dirs):
            rel = os.path.relpath(path, tree)
            with open(path, encoding="utf-8") as fh:
                text = fh.read()
            n = len(text.splitlines())
            if n > FILE_LIMIT:
                long_files.append((rel, n))
            for name, length in qualnames(ast.parse(text, rel)):
                if length > FUNC_LIMIT:
                    long_funcs.append((rel, name, length))
        print(f"== {group}: files over {FILE_LIMIT} lines: {len(long_files)}")
        for rel, n in sorted(long_files, key=lambda t: -t[1]):
            print(f"  {rel}: {n}")
        print(f"== {group}: functions over {FUNC_LIMIT} lines: {len(long_funcs)}")
        for rel, name, length in sorted(long_funcs, key=lambda t: -t[2]):
            print(f"  {rel}:{name}: {length}")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
