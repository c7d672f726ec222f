/* f4d_take.h: the take format: crash-safe, append-only recording of
 * synchronized sets, its reader, and `verify` (check + rebuild the index).
 *
 * A take is a directory:
 *   take.f4t   records, append-only: [header 16 B][payload][crc32(payload) 4 B]
 *              header = magic "F4DR", u16 type, u16 version, u32 payload length,
 *              u32 crc32(first 12 header bytes); all integers little-endian.
 *              Types: 1 take info (cameras, formats), 2 set, 3 end (clean close).
 *   take.idx   index: "F4DI" u32 version, then 24-byte entries
 *              {u64 seq, u64 offset, u32 length, u32 crc32(first 20 bytes)}.
 *              Written as the take grows; rebuilt from take.f4t by verify.
 *   board.json the board the take was recorded with.
 *
 * Durability: a thread of the writer's own calls fdatasync() on take.f4t
 * at most `durability_ms` after a set is appended (later only while an
 * earlier fdatasync is still running), so after a power cut at most the sets
 * appended in the last durability window plus the time of two fdatasyncs
 * are lost (after a kill -9 only a torn last record: the page cache keeps
 * the rest); everything older survives and verify recovers it. Appends never
 * wait for fdatasync: a disk that stalls for seconds delays durability
 * (f4d_take_durable_sets lags), not the appender. Records are never
 * rewritten; verify only truncates a torn tail and rewrites the index
 * atomically (tmp + rename).
 *
 * A failed background fdatasync (or index write) fails the writer: the
 * next append returns F4D_EIO and close names the error, writing no end
 * record (verify then recovers what reached the disk).
 *
 * Test knobs, read at create: F4D_TAKE_TEST_SYNC_DELAY_MS=N makes every
 * background fdatasync N ms slower (a slow disk); F4D_TAKE_TEST_SYNC_FAIL_AFTER=N
 * lets N background fdatasyncs succeed and fails the next with EIO (a dying
 * disk).
 *
 *     struct f4d_take_writer *w;
 *     f4d_take_create(&w, "takes/t1", &info, board_json, 250, err, n);
 *     f4d_take_append(w, set);        // from the synchronizer's on_set
 *     f4d_take_close(w);
 *
 *     struct f4d_take_reader *r;
 *     f4d_take_open(&r, "takes/t1", err, n);
 *     struct f4d_take_set s;
 *     for (uint64_t i = 0; i < f4d_take_count(r); i++) f4d_take_read(r, i, &s);
 *     f4d_take_reader_close(r);
 */
#ifndef F4D_TAKE_H
#define F4D_TAKE_H

#include <stdbool.h>
#include <stdint.h>

#include "hal.h"

#define F4D_TAKE_FILE "take.f4t"
#define F4D_TAKE_INDEX "take.idx"
#define F4D_TAKE_BOARD "board.json"
#define F4D_TAKE_RECORD_MAX (256u << 20) /* largest payload accepted */

enum f4d_take_record_type { F4D_TAKE_REC_INFO = 1, F4D_TAKE_REC_SET = 2, F4D_TAKE_REC_END = 3 };

struct f4d_take_info {
    uint32_t n_cams;
    uint32_t rate_mhz;
    uint32_t durability_ms;
    struct hal_format formats[HAL_RIG_CAMERAS_MAX];
    char cam_ids[HAL_RIG_CAMERAS_MAX][32];
};

/* One recorded frame; `data` points into the reader's buffer. */
struct f4d_take_frame {
    bool present;
    struct hal_buffer meta;   /* status, timestamps, ids, format; data = NULL */
    const uint8_t *data;
    uint32_t bytes;
};
struct f4d_take_set {
    uint64_t seq;
    uint64_t trigger_ts_ns;
    bool complete, has_edge;
    uint32_t present_mask, ok_mask;
    struct f4d_take_frame frames[HAL_RIG_CAMERAS_MAX];
};

/* ---- writer ---- */
struct f4d_take_writer;
int f4d_take_create(struct f4d_take_writer **w, const char *dir, const struct f4d_take_info *info,
                    const char *board_json, uint32_t durability_ms, struct f4d_err *err);
/* Appends one set (frames as the synchronizer holds them). One appending
 * thread; the getters below may be called from any thread. */
int f4d_take_append(struct f4d_take_writer *w, const struct hal_set *set);
/* Sets known to be on stable storage (fdatasync returned after them). */
uint64_t f4d_take_durable_sets(const struct f4d_take_writer *w);
uint64_t f4d_take_bytes_written(const struct f4d_take_writer *w);
uint64_t f4d_take_sets_written(const struct f4d_take_writer *w);
/* Waits for an fdatasync in flight, writes the end record, syncs, closes.
 * Frees w even on error. */
int f4d_take_close(struct f4d_take_writer *w, struct f4d_err *err);

/* ---- reader ---- */
struct f4d_take_reader;
/* Opens a take; uses take.idx when it is consistent, else scans take.f4t. */
int f4d_take_open(struct f4d_take_reader **r, const char *dir, struct f4d_err *err);
const struct f4d_take_info *f4d_take_get_info(const struct f4d_take_reader *r);
uint64_t f4d_take_count(const struct f4d_take_reader *r);
/* Reads set i; frame data stays valid until the next read. F4D_ECORRUPT on a bad CRC. */
int f4d_take_read(struct f4d_take_reader *r, uint64_t i, struct f4d_take_set *out);
void f4d_take_reader_close(struct f4d_take_reader *r);

/* ---- verify ---- */
struct f4d_take_report {
    uint64_t sets;            /* valid set records */
    uint64_t corrupt;         /* records that failed a CRC or structure check (kept, skipped) */
    uint64_t repaired;        /* sets the old index did not list (recovered by the rebuild) */
    uint64_t truncated_bytes; /* torn tail removed */
    bool clean_end;           /* the writer closed the take */
    bool index_rebuilt;
};
/* Scans take.f4t. With `repair`, truncates a torn tail and rewrites take.idx. */
int f4d_take_verify(const char *dir, bool repair, struct f4d_take_report *rep, struct f4d_err *err);

#endif
