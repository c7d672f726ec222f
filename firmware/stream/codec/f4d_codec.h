/* f4d_codec.h - the compressed 4D Gaussian stream: key-frame codec (intra and
 * predicted keys with quantized motion), the packet container, and SPZ
 * import/export. Library f4d_codec; depends on firmware/gaussians/splat (the
 * frame type), zstd (planes), zlib (CRC32, SPZ's gzip) and kernels' status.
 *
 *     codec_enc *enc;  codec_dec *dec;
 *     codec_enc_new(300000, CODEC_Q_MEDIUM, &enc, &err);   // planned once
 *     codec_dec_new(300000, &dec, &err);
 *     uint8_t *pkt = malloc(codec_packet_bound(300000));
 *     size_t n;
 *     codec_enc_key(enc, &key, t_us, CODEC_KEY_AUTO, NULL, pkt, cap, &n);
 *     // ... send pkt[0..n) ...
 *     struct codec_packet p;
 *     if (codec_packet_parse(buf, len, &p, &err) == 0 &&
 *         codec_dec_packet(dec, &p) == 1)
 *         draw(codec_dec_frame(dec));
 *
 * Why the container lives here: the packet is the codec's unit (one key frame
 * per packet, its reference named by sequence number), the transport (SRT,
 * files) only moves opaque packets, and the display decodes them; keeping the
 * framing beside the codec means one reader to validate and fuzz.
 *
 * ---- Packet (all little-endian, 32-byte header) ----
 *   0  u32 magic 0x50443446 ("F4DP")     4  u8 version (3; 1, 2 read) 5 u8 type
 *   6  u16 flags (0)                     8  u32 seq (per packet, +1 each)
 *   12 u32 ref_seq (predicted: seq of the key it is coded against; else seq)
 *   16 u64 timestamp in microseconds     24 u32 payload length (<= 1 GiB)
 *   28 u32 CRC32 (zlib polynomial) of bytes 0..27 followed by the payload
 * Types: 1 stream header (codec version, quality, capacity hint), 2 intra key,
 * 3 predicted key, 4 end of stream. A stream file is packets back to back; a
 * receiver joins anywhere: codec_packet_resync finds the next packet boundary,
 * predicted keys are skipped (and counted) until an intra key arrives, a seq
 * gap counts lost packets, and a predicted key whose ref_seq is not the key
 * the decoder holds is skipped until the next intra key.
 *
 * ---- Key frame payload ----
 * A 20-byte frame header (version 2: then 6 f32 predictor coefficients, see
 * below), 16 channel quantizers (f32 lo, f32 step: position
 * x y z, log-scale x y z, opacity, rgb, motion_bwd x y z, motion_fwd x y z),
 * then planes. Each plane is one attribute component for every coded Gaussian,
 * as unsigned integers (residuals zigzagged), optionally delta-coded along the
 * index, byte-shuffled (all low bytes, then the next ...) and zstd-compressed:
 * [u8 transform | width << 4][u32 compressed length][zstd frame].
 * Transforms: 0 none, 1 delta, 2 delta of signed values, version 3: 3 the
 * signed value minus the median of the three before it (a neighbour's noise
 * is not doubled); bit 2 (residual planes): in Morton order. Widths 1-4
 * bytes; version 3: 5 / 6 / 7 = values of 1 / 2 / 4 bits packed 8 / 4 / 2 a
 * byte, low bits first (zstd's literals cost a bit or more a byte, so a
 * plane of 0 and +-1 costs about its entropy packed). The encoder keeps the
 * smallest. Frame header byte 2: bit 0 motion, bit 1 explicit match,
 * version 3: bit 2 block parameters present, bit 3 block mf, bit 4 block
 * rotation (bit 2 set exactly when 3 or 4 is; predicted keys with motion).
 *   block motion (version 3, predicted keys whose motions span the key
 *     interval): the matched Gaussians in the Morton order of their
 *     predicted positions are cut into blocks of 64; after the flags plane
 *     come 15 planes of one zigzagged integer per block (|v| <= 2^22):
 *     t x y z (in 1/8 mf steps, sent minus the previous block's motion at
 *     this block's origin), M (3x3 row-major, one unit = 1/8 mf step across
 *     10 cm), dq x y z (w >= 0, in 1/16 rotation steps). Block mf: mf is
 *     predicted as t + M (P - o) (P the decoded position, o the predicted
 *     position of the block's first Gaussian) and its residual is in half
 *     mf steps; block rotation: a rotation is predicted as dq * reference
 *     rotation. A rigid part's Gaussians then cost nothing but their noise
 *     leaving the bound. The encoder sends each only where the planes it
 *     would write measure smaller (sparse takes and fine levels may not).
 *   intra: position (q = round((p - lo) / step), bits chosen per frame from the
 *     bounds: the quality's minimum bits, more when the extent demands, so the
 *     error is <= step / 2 <= the quality's metric cap), log-scale (fixed step,
 *     scales clamped to >= 1e-7 m), opacity and rgb (fixed bits over the
 *     frame's range), rotation as smallest-three (2-bit index + 3 x rot_bits),
 *     motions (fixed metric step).
 *   predicted: each Gaussian is matched to one of the reference key (the
 *     previous decoded key, positions moved by its motion_fwd; motion_fwd is
 *     predicted to continue, motion_bwd to undo it). Identity correspondence by
 *     default (pixel-aligned Gaussians keep their index); an explicit match
 *     array is coded as deltas of the reference index (0 when the next index
 *     follows). A flag plane says per Gaussian: 0 unchanged (all residuals
 *     quantize to 0: nothing else stored, the zstd'd flag costs < 1 bit),
 *     1 changed (residuals of every channel, on the same steps as intra),
 *     2 new (intra-coded). Reference Gaussians no one matches are dropped.
 *     The encoder predicts from its own reconstruction, so errors never
 *     accumulate: every value is within the intra bound of the input.
 *
 * Predictor (version 2). The reference's motions need not span the key
 * interval (a 30 fps take keyed at 10 Hz carries 1/30 s motions), so the
 * encoder fits, per key, by least squares over the matched Gaussians,
 *   displacement ~ c0 mf + c1 mb,  mf ~ c2 mf + c3 mb,  mb ~ c4 mf + c5 mb
 * (mf, mb: the reference's decoded motions) and sends c0..c5 (f32); version 1
 * streams use (1, 0, 1, 0, -1, 0). With exact key-interval motion the fit
 * finds that; with 1/3-interval motion it finds the second-order
 * extrapolation (about 6 mf + 3 mb). The decoder checks |c| <= 1000.
 *
 * Quality levels (error bounds, per value, against the encoder's input):
 *                      COMPACT          LOW               MEDIUM             HIGH
 *   position     step <= 2 mm, >=10 b step <= 1 mm, >=12 b <= 0.1 mm, >=16 b <= 0.02 mm, >=18 b
 *   log-scale    step 1/8             step 1/8             step 1/32          step 1/128
 *   opacity/rgb  5 bits / 6 bits      6 bits / 6 bits      8 / 8              10 / 10  (of range)
 *   rotation     6 bits per comp.     7 bits per comp.     10                 12
 *   motion       step 2 mm            step 1 mm            step 0.1 mm        step 0.02 mm
 * (COMPACT, number 3, came with version 2.)
 * The error bound is half a step (positions: the step is the frame's extent
 * over 2^bits - 1, so a 5 m scene at MEDIUM gets 16 bits = 76 um, i.e. 38 um
 * worst case; the 0.1 mm cap adds bits only beyond 6.5 m; rgb/opacity:
 * range / (2^bits - 1) / 2; rotation components: one rotation step
 * sqrt(2) / (2^bits - 1)). Predicted keys keep a reference value already
 * within half a step (+0.05 %), so the bounds hold for every key. Version 2
 * widens three dead zones where the render cannot tell: a rotation is kept
 * while 2 x angle x (s_max - s_min) (how far it moves the 2-sigma
 * ellipsoid) stays within the position bound; with motions that span the key
 * interval (fitted c0 ~ 1, c1 ~ 0, "keyed") mf is kept while the next key's
 * prediction (this decoded position + decoded mf) lands within 0.9 position
 * bounds of the true next position (so mf is within 2 position bounds), and
 * mb, predicted as the way back to the decoded reference, is kept within 2
 * position bounds + half a motion step.
 * Measured, version 3 (f4d-bench codec; walk preset, 37.6k Gaussians with
 * motion over the key interval, 10 Hz keys, render PSNR vs uncompressed, 4
 * rig cameras 518x518, float renders; version 2 in brackets):
 *   COMPACT intra 3.84 B/G, predicted 0.73 B/G [1.34], 49.7 dB (min 49.2)
 *   LOW     intra 4.51 B/G, predicted 1.10 B/G [1.59], 51.7 dB (min 50.9)
 *   MEDIUM  intra 6.81 B/G, predicted 2.11 B/G [2.52], 60.4 dB (min 59.1)
 *   HIGH    intra 8.43 B/G, predicted 2.84 B/G [3.36], 72.1 dB (min 69.8)
 *   the walk at 292.7k Gaussians, COMPACT: intra 3.47, predicted 0.28 [0.85]
 *   the same in stream order (codec_enc_set_reorder): intra 2.67, predicted
 *   0.28, 11.6 Mbit/s at 10 Hz keys with an intra key a second (effort MAX:
 *   2.24 / 0.25, 10.1 Mbit/s), 47.9 dB
 *   (SPZ v4 by codec_spz_encode, same key: 5.98 B/G, 56.5 dB, no motion.)
 *
 * Non-finite input: the encoder refuses a frame with a NaN or Inf anywhere
 * (F4D_EINVAL naming the Gaussian and attribute); the decoders never produce
 * one (quantizers must be finite, results are checked: F4D_EFORMAT).
 * Memory: encoder and decoder are planned for `capacity` Gaussians at _new
 * (frames, planes, zstd workspaces as static contexts); encoding or decoding a
 * frame up to the capacity allocates nothing, a larger one is refused
 * (F4D_ERANGE). SPZ functions allocate (files, not the frame path).
 */
#ifndef F4D_CODEC_H
#define F4D_CODEC_H

#include <stddef.h>
#include <stdint.h>

#include "f4d_status.h"
#include "splat.h"

#ifdef __cplusplus
extern "C" {
#endif

#define CODEC_VERSION        3   /* written; 1, 2 and 3 are read */
#define CODEC_PACKET_MAGIC   0x50443446u /* "F4DP" little-endian */
#define CODEC_PACKET_HEADER  32
#define CODEC_PAYLOAD_MAX    (1u << 30)
#define CODEC_CAPACITY_MAX   ((size_t)1 << 24) /* Gaussians per frame */

/* Stored in stream headers: never renumbered. */
enum codec_quality {
    CODEC_Q_LOW    = 0,
    CODEC_Q_MEDIUM = 1,
    CODEC_Q_HIGH   = 2,
    CODEC_Q_COMPACT = 3, /* version 2: the streaming level, below LOW (about 45-47 dB) */
    CODEC_QUALITY_COUNT
};

enum codec_packet_type {
    CODEC_PKT_STREAM = 1,
    CODEC_PKT_INTRA  = 2,
    CODEC_PKT_PRED   = 3,
    CODEC_PKT_END    = 4,
};

/* The error bounds of a level (see the table above). */
struct codec_quality_info {
    const char *name;
    int   pos_bits_min;      float pos_step_max;    /* metres */
    float log_scale_step;    int   opacity_bits;
    int   rgb_bits;          int   rot_bits;
    float motion_step;       /* metres */
};
const struct codec_quality_info *codec_quality_get(enum codec_quality q); /* NULL if out of range */
int codec_quality_from_name(const char *name, struct f4d_err *err);       /* low|medium|high|compact */

/* ---- packets ---- */
struct codec_packet {
    int            type;
    int            version;     /* codec version of the packet (1..CODEC_VERSION) */
    uint32_t       seq, ref_seq;
    uint64_t       t_us;
    const uint8_t *payload;     /* points into the parsed buffer */
    size_t         payload_len;
    size_t         size;        /* header + payload */
};
/* Largest packet a key frame of `capacity` Gaussians can take. */
size_t codec_packet_bound(size_t capacity);
/* Parses and checks one packet at buf[0..len): magic, version, type, length,
 * CRC. F4D_EEOF: the buffer ends before the packet does (read more);
 * F4D_ECORRUPT: CRC mismatch; F4D_EFORMAT: anything else malformed. */
int    codec_packet_parse(const uint8_t *buf, size_t len, struct codec_packet *p, struct f4d_err *err);
/* How many Gaussians a parsed packet plans for, before any decoding: a stream
 * header's capacity hint, or an intra / predicted key's count (so a receiver
 * that joins after the header sizes its decoder from the first intra key).
 * F4D_EFORMAT for other packet types or a payload too short to say. */
int    codec_packet_gaussians(const struct codec_packet *p, size_t *n, struct f4d_err *err);
/* Offset of the next possible packet start after buf[0] (a magic), or len. */
size_t codec_packet_resync(const uint8_t *buf, size_t len);
/* Writes a packet around `payload` (may alias out + CODEC_PACKET_HEADER). */
int    codec_packet_write(uint8_t *out, size_t cap, int type, uint32_t seq, uint32_t ref_seq,
                          uint64_t t_us, const uint8_t *payload, size_t payload_len, size_t *len,
                          struct f4d_err *err);

/* ---- encoder ---- */
typedef struct codec_enc codec_enc;

enum codec_key_mode {
    CODEC_KEY_AUTO  = 0, /* predicted when a reference exists, else intra */
    CODEC_KEY_INTRA = 1,
    CODEC_KEY_STILL = 2, /* intra, Gaussians reordered (Morton order of their
                          * positions) for size: decoded Gaussian j is input
                          * Gaussian codec_enc_order(e)[j], and the next key
                          * is intra (for still files, SPZ-like use) */
};

/* Bytes of the last encoded key by group (payload, before the packet header)
 * and by channel (residual + new planes of one attribute component; the
 * channels are named by codec_channel_name). */
#define CODEC_CHANNELS 20
struct codec_enc_stats {
    int    intra;
    size_t count, unchanged, changed, fresh, dropped;
    size_t bytes_total, bytes_header, bytes_index, bytes_pos, bytes_attr, bytes_motion;
    size_t bytes_flags, bytes_match;         /* parts of bytes_index */
    size_t bytes_blocks;                     /* block motion (part of bytes_motion) */
    size_t bytes_channel[CODEC_CHANNELS];
    float  predictor[7];                     /* see "Predictor" above */
};
/* "pos.x" ... "mf.z"; NULL when ch is out of range. */
const char *codec_channel_name(int ch);

int  codec_enc_new  (size_t capacity, enum codec_quality q, codec_enc **out, struct f4d_err *err);
void codec_enc_free (codec_enc *e);
const char *codec_enc_error(const codec_enc *e);
/* Writes an older codec version (2: no packed planes, median prediction or
 * block motion) for decoders that read only that; default CODEC_VERSION. */
int  codec_enc_set_version(codec_enc *e, int version);
/* The stream header packet (type 1), first in a file. */
int  codec_enc_stream_header(codec_enc *e, uint64_t t_us, uint8_t *out, size_t cap, size_t *len);
/* Encodes key frame f (motion optional) as one packet. match: NULL (identity:
 * Gaussian i continues reference i; extra ones are new, missing ones dropped)
 * or [f->count] reference indices, -1 for a new Gaussian. */
int  codec_enc_key  (codec_enc *e, const struct splat_frame *f, uint64_t t_us, enum codec_key_mode mode,
                     const int32_t *match, uint8_t *out, size_t cap, size_t *len);
/* End-of-stream packet. */
int  codec_enc_end  (codec_enc *e, uint64_t t_us, uint8_t *out, size_t cap, size_t *len);
/* What a decoder holds after the last key (the encoder's reconstruction). */
const struct splat_frame *codec_enc_recon(const codec_enc *e);
const struct codec_enc_stats *codec_enc_last(const codec_enc *e);
/* Encoder effort (default CODEC_EFFORT_DEFAULT; the stream format is the
 * same at every effort, only the encoder's searching differs):
 *   FAST     candidates and planes at zstd level 1 (live encoders short of CPU)
 *   DEFAULT  candidates and planes at zstd level 5
 *   MAX      candidates at level 5, the chosen planes again at level 19
 *            (archives, offline streams: several times the default's CPU)
 * Allocates a larger zstd workspace (at capacity) where the level needs it. */
enum codec_effort { CODEC_EFFORT_FAST = 0, CODEC_EFFORT_DEFAULT = 1, CODEC_EFFORT_MAX = 2 };
int  codec_enc_set_effort(codec_enc *e, int effort);
int  codec_effort_from_name(const char *name, struct f4d_err *err); /* fast|default|max */
/* Stream order (default off): every key is coded in an order of the
 * encoder's choosing instead of the input's, which the decoder needs no
 * word of (it is what any decoder of these versions reads): an intra key in
 * the Morton order of its positions (neighbours in space get neighbouring
 * indices, so every plane's deltas shrink: the 300k walk's intra key 3.48 ->
 * 2.67 B/G), a predicted key in the order of the reference slots its
 * Gaussians continue, new ones last. The match argument of codec_enc_key
 * keeps naming the previous key's INPUT indices; decoded Gaussian j is input
 * Gaussian codec_enc_order(e)[j]. Switching it forces the next key intra.
 * Allocates its buffers (capacity) on the first call with on = 1. */
int  codec_enc_set_reorder(codec_enc *e, int on);
/* Input index of each decoded Gaussian of the last key when it was
 * CODEC_KEY_STILL or the stream order is on; NULL when the order is the
 * input's. Valid until the next call. */
const uint32_t *codec_enc_order(const codec_enc *e);

/* ---- decoder ---- */
typedef struct codec_dec codec_dec;

struct codec_dec_stats {
    uint64_t packets, intra, predicted;
    uint64_t lost;           /* packets missing from seq gaps                 */
    uint64_t skipped;        /* predicted keys without their reference        */
    uint64_t refused;        /* packets whose payload failed validation       */
};

int  codec_dec_new  (size_t capacity, codec_dec **out, struct f4d_err *err);
void codec_dec_free (codec_dec *d);
const char *codec_dec_error(const codec_dec *d);
/* Feeds one parsed packet. Returns 1 when a key frame was decoded (then
 * codec_dec_frame / codec_dec_time hold it), 0 when the packet carried no
 * frame or was skipped (no reference yet, reference lost), < 0 when its
 * payload is malformed (counted as refused; the decoder then waits for the
 * next intra key). */
int  codec_dec_packet(codec_dec *d, const struct codec_packet *p);
const struct splat_frame *codec_dec_frame(const codec_dec *d);
uint64_t codec_dec_time (const codec_dec *d);
const struct codec_dec_stats *codec_dec_stats(const codec_dec *d);
/* The stream header fields seen last (0 when none). */
int  codec_dec_quality(const codec_dec *d);

/* ---- SPZ (Niantic) and interop ----
 * Written as SPZ v4, the current version (32-byte plain header: magic "NGSP",
 * version 4, numPoints, shDegree 0, fractionalBits 12, flags 0, numStreams 5,
 * tocByteOffset 32; a TOC of (compressed, uncompressed) u64 pairs; one zstd
 * frame per array: positions, alphas, colours, scales, rotations) or, on
 * request, v3 (16-byte header and the same arrays, gzipped). Arrays:
 * positions 24-bit fixed point (1/4096 m), alpha u8 (sigmoid(logit) * 255),
 * colour u8 (f_dc * 0.15 * 255 + 127.5), log-scale u8 ((s + 10) * 16),
 * rotation smallest-three in a u32 (2-bit index, 3 x 10 bits).
 * Axes: SPZ stores RUB; our frames (like INRIA PLY) are taken as RDF, so y and
 * z of positions and quaternions are flipped on the way in and out. Read: v2
 * and v3 (gzip) and v4 (extension records skipped through tocByteOffset, SH
 * streams read and ignored). Round-trip error: 0.12 mm in position, 1/32 in
 * log-scale, 1/510 in opacity, (1/255)/0.15*C0/2 in rgb. */
int codec_spz_encode_version(const struct splat_frame *f, int version, uint8_t **out, size_t *len,
                             struct f4d_err *err); /* version 3 or 4 */
int codec_spz_encode(const struct splat_frame *f, uint8_t **out, size_t *len, struct f4d_err *err); /* v4 */
int codec_spz_decode(const uint8_t *buf, size_t len, struct splat_frame *f, struct f4d_err *err);
int codec_spz_write (const char *path, const struct splat_frame *f, struct f4d_err *err);
int codec_spz_read  (const char *path, struct splat_frame *f, struct f4d_err *err);

#ifdef __cplusplus
}
#endif
#endif /* F4D_CODEC_H */
