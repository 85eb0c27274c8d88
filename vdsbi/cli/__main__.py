from ._main import entry

entry()
