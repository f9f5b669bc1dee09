"""accellog's own reader of finished MCAP files, beside the ``mcap`` library (issue #26).

Why: the recorder writes one protobuf message per FIFO read (~25-40 samples, ~25-40 messages/s at
1 kHz: a 1 h session is ~100 k messages), so the per-message Python of ``mcap``'s reader
(``make_reader(...).iter_messages()`` + accellog's per-message decoder, ``store/collect.py``)
dominates a read. This path maps the file, parses footer and summary with struct (``index``,
``summary``, ``records``), decompresses runs of chunks into reused buffers (``decompress``), finds
the Message records (``record_starts``) and decodes all messages of a chunk group at once with numpy
(``field_walk``, ``batch_decode``, ``byte_views``); ``fastread`` drives it.

Measured (``benchmarks/bench_mcap_read.py``: ``read_session``, best CPU time of 3, the generic
reader forced by ``accellog.store.reader.FAST_READ = False``): a 1 h recorder-layout file (3.6 M
samples in 100 k messages of 30-42 samples, written by ``bench_readback.write_recorder_layout``)
0.48 s fast vs 1.90 s generic (4.0x); /tmp/accellog_bench/fit_3600s.mcap (whole-session writer,
7,200 messages of 500 samples) 0.27 s vs 0.37 s (1.4x): the gain grows with the message count.

What stays on the ``mcap`` library: the writer, the salvage of unfinished files
(``store/collect.py``'s ``recover``), and reading anything outside the canonical layout (files other
tools wrote): every surprise raises ``index.NotFast`` and ``store/collect.py`` reads the file instead,
with identical results where both apply.
"""
