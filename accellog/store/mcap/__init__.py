"""accellog's own reader of finished MCAP files, beside the ``mcap`` library (issue #26).

Why: the recorder writes one protobuf message per FIFO read (~25-40 samples, ~70 messages/s at
1 kHz: a 1 h session is ~250 k messages), so the per-message Python of ``mcap``'s reader
(``make_reader(...).iter_messages()`` + accellog's per-message decoder, ``store/collect.py``)
dominates a read. This path maps the file, parses footer and summary with struct (``index``,
``summary``, ``records``), decompresses runs of chunks into reused buffers (``decompress``), finds
the Message records (``record_starts``) and decodes all messages of a chunk group at once with numpy
(``field_walk``, ``batch_decode``, ``byte_views``); ``fastread`` drives it.

Measured: ``read_session`` of /tmp/accellog_bench/fit_3600s.mcap (3.6 M samples, 7,200 messages of
500 samples), CPU time: 0.27 s fast path vs 0.89 s with ``accellog.store.reader.FAST_READ = False``
(``mcap``'s reader + per-message decoding); recorder-layout files (one message per FIFO read) widen
the gap: ``benchmarks/bench_readback.py`` ('generic' rows).

What stays on the ``mcap`` library: the writer, the salvage of unfinished files
(``store/collect.py``'s ``recover``), and reading anything outside the canonical layout (files other
tools wrote): every surprise raises ``index.NotFast`` and ``store/collect.py`` reads the file instead,
with identical results where both apply.
"""
