"""The type stub names every option infer() takes, and nothing else."""

import ast
from pathlib import Path

import grainforce as gf

STUB = Path(gf.__file__).with_name("__init__.pyi")


def test_stub_lists_the_configuration_fields():
    tree = ast.parse(STUB.read_text())
    infer = next(n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == "infer")
    keywords = {a.arg.rstrip("_") for a in infer.args.kwonlyargs} - {"progress"}
    keywords |= {"method"}
    assert keywords == set(gf._defaults())
