"""The resident render process (issue 17, item 5): a per-user server that keeps numba's kernels loaded, so that
``pfn-render`` starts fast.

A fresh ``pfn-render`` spends about a second importing numba and loading its kernels before any work of ours
(bench/README.md, ``bench_cli_startup.py``); no change inside a fresh process removes that. ``pfn-resident
start`` runs one long-lived process per user that has paid it once; ``pfn-render``
(:mod:`photon_fields.runtime.cli.render_entry`) asks it first, with the standard library only, and hands it the
command line when it is running and runs the same code with the same environment; otherwise it renders in its own
process as before, silently. The server runs the
job by calling ``pfn-render``'s own main in the client's folder, with the client's output streams, so the files
and the text are what an in-process run gives.

Modules: ``paths`` (the per-user folder and its files), ``fingerprint`` (what must match: code and environment),
``protocol`` (length-prefixed JSON messages, checked strictly), ``client`` (pfn-render's side), ``job`` (one render
inside the server, as a fresh process would run it), ``warmup`` (the kernels loaded at start), ``server``,
``cli`` (``pfn-resident start / stop / status``). Linux only (Unix sockets with ``SO_PEERCRED``); elsewhere
``pfn-render`` always renders in-process. docs/resident.md has the design and the trade-off: the server holds its
memory while it waits (it exits after ``--idle-minutes`` without jobs).
"""
