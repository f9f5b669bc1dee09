"""The plain-numpy floor of a session command's work (benchmarks/run_all.py, the `cpu` rows).

    python benchmarks/floor_numpy.py SESSION.mcap

What `fit` must do at least, with plain libraries and no accellog: import numpy + zstandard,
zstd-decompress every chunk of the MCAP file (one at a time), walk its records and the protobuf
fields of each ImuBatch and PoseLabel message (accellog_v1.proto: packed sfixed counts), gather the
packed count arrays (one vectorised take per chunk and field), convert them to float, cut every
labelled hold (trimmed) into 1 s window means, its autocorrelation time (block-averaged FFT, as
accellog.navigate.stream_sums), the gyro and temperature means, and model3 (reading = S up + b)
by least squares. The series are concatenated whole: its memory is not a floor, its CPU time is.
"""

import struct
import sys

import numpy as np
import zstandard

WINDOW_S, TRIM_S, BLOCK = 1.0, 0.5, 4096
PACKED = {2: "<i8", 3: "<i4", 4: "<i4", 5: "<i4"}  # ImuBatch: t_ns, accel, gyro, temperature counts


def fields(b, i, end):
    """{field: value (varint) or (start, stop) (length-delimited)} of one protobuf message b[i:end]."""
    out = {}
    while i < end:
        key = b[i]
        i += 1
        wt = key & 7
        if wt == 0 or wt == 2:
            v, s = 0, 0
            while b[i] & 128:
                v |= (b[i] & 127) << s
                s += 7
                i += 1
            v |= b[i] << s
            i += 1
            if wt == 0:
                out[key >> 3] = v
            else:
                out[key >> 3] = (i, i + v)
                i += v
        else:
            n = 8 if wt == 1 else 4
            out[key >> 3] = (i, i + n)
            i += n
    return out


def gather(buf, spans, dtype):
    """The packed arrays at spans [(start, stop)] of buf, concatenated (one vectorised take)."""
    s = np.array(spans, np.int64).reshape(-1, 2)
    lens = s[:, 1] - s[:, 0]
    idx = np.repeat(s[:, 0] - np.concatenate([[0], np.cumsum(lens)[:-1]]), lens) + np.arange(lens.sum())
    return np.frombuffer(buf, np.uint8)[idx].view(dtype)


with open(sys.argv[1], "rb") as fh:
    data = fh.read()
dctx = zstandard.ZstdDecompressor()
topics, cols, poses = {}, {k: [] for k in PACKED}, []


def walk(b, i, end):
    """The records of b[i:end]: channels named, /imu packed fields gathered, /poses decoded; a chunk's
    records decompressed and walked the same way (one chunk in memory at a time)."""
    spans = {k: [] for k in PACKED}
    while i < end:
        op, n = b[i], struct.unpack_from("<Q", b, i + 1)[0]
        i += 9
        if op == 0x05:  # message: channel, sequence, log and publish time, data
            topic = topics.get(b[i] | b[i + 1] << 8)
            if topic == "/imu":
                f = fields(b, i + 22, i + n)
                for k, sp in spans.items():
                    if k in f:
                        sp.append(f[k])
            elif topic == "/poses":
                f = fields(b, i + 22, i + n)
                a, z = f[4]
                poses.append((f.get(2, 0) * 1e-9, f.get(3, 0) * 1e-9, np.frombuffer(b[a:z], "<f8")))
        elif op == 0x04:  # channel: id, schema id, topic
            cid, _, tl = struct.unpack_from("<HHI", b, i)
            topics[cid] = bytes(b[i + 8 : i + 8 + tl]).decode()
        elif op == 0x06:  # chunk: times, size, crc, compression, records
            usize = struct.unpack_from("<Q", b, i + 16)[0]
            cl = struct.unpack_from("<I", b, i + 28)[0]
            comp = bytes(b[i + 32 : i + 32 + cl])
            rl = struct.unpack_from("<Q", b, i + 32 + cl)[0]
            r0 = i + 40 + cl
            raw = b[r0 : r0 + rl] if comp == b"" else dctx.decompress(b[r0 : r0 + rl], max_output_size=usize)
            walk(raw, 0, len(raw))
        elif op == 0x0F:  # data end
            break
        i += n
    for k, sp in spans.items():
        if sp:
            cols[k].append(gather(b, sp, PACKED[k]))


walk(memoryview(data), 8, len(data) - 8)
t = np.concatenate(cols[2]) * 1e-9
acc = np.concatenate(cols[3]).reshape(-1, 3) / 16384.0
gyr = np.concatenate(cols[4]).reshape(-1, 3) / 131.0
temp = np.concatenate(cols[5]) / 333.87 + 21.0
# each trimmed hold: window means, its autocorrelation time (block-averaged FFT), gyro and temperature means
rows, ups, holds = [], [], []
for t0, t1, up in poses:
    a, b = np.searchsorted(t, [t0 + TRIM_S, t1 - TRIM_S])
    nw = int((t[b - 1] - t[a]) // WINDOW_S) if b > a else 0
    if nw < 1:
        continue
    x = acc[a:b]
    edges = np.searchsorted(t[a:b], t[a] + WINDOW_S * np.arange(nw + 1))
    cs = np.concatenate([np.zeros((1, 3)), np.cumsum(x, axis=0)])
    rows.append((cs[edges[1:]] - cs[edges[:-1]]) / np.diff(edges)[:, None])
    ups.append(np.repeat(up[None, :], nw, axis=0))
    nb, tau = x.shape[0] // BLOCK, np.ones(3)
    if nb:
        y = (x[: nb * BLOCK] - x.mean(axis=0)).reshape(nb, BLOCK, 3)
        p = np.fft.rfft(y, 2 * BLOCK, axis=1)
        ac = np.fft.irfft((p * np.conj(p)).real.sum(axis=0), 2 * BLOCK, axis=0)[:BLOCK]
        tau = 1 + 2 * np.sum(ac[1:200] / ac[0], axis=0)
    holds.append((tau, gyr[a:b].mean(axis=0), temp[a:b].mean()))
meas, up = np.concatenate(rows), np.concatenate(ups)
theta, *_ = np.linalg.lstsq(np.column_stack([up, np.ones(up.shape[0])]), meas, rcond=None)  # model3: S up + b
print(
    f"{acc.shape[0]} samples, {len(holds)} holds, b = {theta[3]} g, tau max {max(h[0].max() for h in holds):.2f}"
)
