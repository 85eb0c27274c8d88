"""The process's compute resources, apart from the physics: compiled programs under the
kernel's memory-map limit, and stages compiled or run on a second thread."""

from ._programs import (
    in_background as in_background,
    memory_map_usage as memory_map_usage,
    release_compiled_programs as release_compiled_programs,
    thread_map as thread_map,
)
