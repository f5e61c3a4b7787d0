"""Exit 1 unless the compiled kernel this process loads is built with AddressSanitizer (``make sanitize``).

``make sanitize`` sets ``CC`` to a compiler with ``-fsanitize=address,undefined`` and a cache folder of its own;
this check, run in the same environment before the tests, makes sure the tests exercise that build and not a
plain one (a kernel that could not be built would leave every caller on its torch path, unchecked).
"""
import os
import sys

from sdm.mapping import build

if __name__ == "__main__":
    if build.library() is None:
        sys.exit("make sanitize: the compiled kernel could not be built with the sanitizers (see the warning)")
    library = build.cache_files()[0]
    if b"__asan_init" not in library.read_bytes():
        sys.exit(f"make sanitize: {library} is not built with AddressSanitizer (CC={os.environ.get('CC')!r})")
    print(f"make sanitize: kernel {library.name} built with AddressSanitizer and UndefinedBehaviorSanitizer")
