"""SHA-256 (FIPS 180-4) as a compiled kernel, for MAVLink 2 signatures computed inside other kernels.

``hashlib`` is faster per byte, but a signature covers under a hundred bytes, and calling it from
Python costs a dozen interpreter operations around each frame (building the key + frame bytes,
the digest object, slicing): more than the hash. ``sha256_into`` lets ``signing`` sign and
check a whole datagram in one compiled call. Tested against ``hashlib``.

- ``sha256_into(a, na, b, nb, out)``: the digest of ``a[:na] + b[:nb]`` (a key and a frame,
  without joining them) into ``out[:32]``.

Words are held in int64 and masked to 32 bits (numba's uint32 arithmetic promotes to int64 anyway).
"""

import numpy as np

from sim_vehicles.common.jit import kernel

_M = 0xFFFFFFFF
_K = np.array(
    [
        0x428A2F98, 0x71374491, 0xB5C0FBCF, 0xE9B5DBA5, 0x3956C25B, 0x59F111F1, 0x923F82A4, 0xAB1C5ED5,
        0xD807AA98, 0x12835B01, 0x243185BE, 0x550C7DC3, 0x72BE5D74, 0x80DEB1FE, 0x9BDC06A7, 0xC19BF174,
        0xE49B69C1, 0xEFBE4786, 0x0FC19DC6, 0x240CA1CC, 0x2DE92C6F, 0x4A7484AA, 0x5CB0A9DC, 0x76F988DA,
        0x983E5152, 0xA831C66D, 0xB00327C8, 0xBF597FC7, 0xC6E00BF3, 0xD5A79147, 0x06CA6351, 0x14292967,
        0x27B70A85, 0x2E1B2138, 0x4D2C6DFC, 0x53380D13, 0x650A7354, 0x766A0ABB, 0x81C2C92E, 0x92722C85,
        0xA2BFE8A1, 0xA81A664B, 0xC24B8B70, 0xC76C51A3, 0xD192E819, 0xD6990624, 0xF40E3585, 0x106AA070,
        0x19A4C116, 0x1E376C08, 0x2748774C, 0x34B0BCB5, 0x391C0CB3, 0x4ED8AA4A, 0x5B9CCA4F, 0x682E6FF3,
        0x748F82EE, 0x78A5636F, 0x84C87814, 0x8CC70208, 0x90BEFFFA, 0xA4506CEB, 0xBEF9A3F7, 0xC67178F2,
    ],
    dtype=np.int64,
)  # fmt: skip
_H0 = np.array(
    [0x6A09E667, 0xBB67AE85, 0x3C6EF372, 0xA54FF53A, 0x510E527F, 0x9B05688C, 0x1F83D9AB, 0x5BE0CD19],
    dtype=np.int64,
)


@kernel
def _rotr(x, n):
    return ((x >> n) | (x << (32 - n))) & _M


@kernel
def _compress(h, buf, at, w):
    """One 64-byte block ``buf[at:at + 64]`` into the state ``h``."""
    for t in range(16):
        i = at + 4 * t
        w[t] = (
            (np.int64(buf[i]) << 24) | (np.int64(buf[i + 1]) << 16) | (np.int64(buf[i + 2]) << 8) | buf[i + 3]
        )
    for t in range(16, 64):
        x, y = w[t - 15], w[t - 2]
        s0 = _rotr(x, 7) ^ _rotr(x, 18) ^ (x >> 3)
        s1 = _rotr(y, 17) ^ _rotr(y, 19) ^ (y >> 10)
        w[t] = (w[t - 16] + s0 + w[t - 7] + s1) & _M
    a0, b0, c0, d0, e0, f0, g0, h0 = h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7]
    for t in range(64):
        t1 = h0 + (_rotr(e0, 6) ^ _rotr(e0, 11) ^ _rotr(e0, 25)) + ((e0 & f0) ^ (~e0 & _M & g0))
        t1 = (t1 + _K[t] + w[t]) & _M
        t2 = ((_rotr(a0, 2) ^ _rotr(a0, 13) ^ _rotr(a0, 22)) + ((a0 & b0) ^ (a0 & c0) ^ (b0 & c0))) & _M
        h0, g0, f0, e0 = g0, f0, e0, (d0 + t1) & _M
        d0, c0, b0, a0 = c0, b0, a0, (t1 + t2) & _M
    h[0] = (h[0] + a0) & _M
    h[1] = (h[1] + b0) & _M
    h[2] = (h[2] + c0) & _M
    h[3] = (h[3] + d0) & _M
    h[4] = (h[4] + e0) & _M
    h[5] = (h[5] + f0) & _M
    h[6] = (h[6] + g0) & _M
    h[7] = (h[7] + h0) & _M


@kernel
def sha256_into(a, na, b, nb, out):
    n = na + nb
    total = (n + 9 + 63) // 64 * 64  # the message, 0x80, zeros, its length in bits (8 bytes)
    buf = np.zeros(total, np.uint8)
    for i in range(na):
        buf[i] = a[i]
    for i in range(nb):
        buf[na + i] = b[i]
    buf[n] = 0x80
    bits = np.int64(n) * 8
    for j in range(8):
        buf[total - 1 - j] = (bits >> (8 * j)) & 0xFF
    h = _H0.copy()
    w = np.empty(64, np.int64)
    for at in range(0, total, 64):
        _compress(h, buf, at, w)
    for k in range(8):
        for j in range(4):
            out[4 * k + j] = (h[k] >> (24 - 8 * j)) & 0xFF
