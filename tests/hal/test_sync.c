/* test_sync.c: the synchronizer, by hand-made frames and under the sim
 * backend's fault injection over >= 10,000 triggers. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "f4d_capture.h"
#include "f4d_sync.h"
#include "hal_board.h"
#include "hal_registry.h"
#include "hal_sim.h"

/* ---- hand-made frames ---- */
struct sink {
    uint32_t sets, marked, released;
    uint64_t last_seq;
    uint32_t last_ok_mask;
};
static void sink_set(void *u, const struct hal_set *s)
{
    struct sink *k = u;
    k->sets++;
    k->marked += !s->complete;
    k->last_seq = s->seq;
    k->last_ok_mask = s->ok_mask;
}
static void sink_release(void *u, struct hal_buffer *b)
{
    (void)b;
    ((struct sink *)u)->released++;
}

static struct hal_buffer frame(uint32_t cam, uint64_t seq, uint64_t dev_ts, uint64_t host_ts)
{
    struct hal_buffer b = {0};
    b.camera_index = cam;
    b.trigger_seq = seq;
    b.device_ts_ns = dev_ts;
    b.host_ts_ns = host_ts;
    b.status = HAL_FRAME_OK;
    return b;
}

static void sync_by_hand(void **state)
{
    (void)state;
    struct sink k = {0};
    struct f4d_sync s;
    struct f4d_sync_config cfg = {2, 1000, 20000, HAL_INCOMPLETE_MARK, 4, 1};
    assert_int_equal(f4d_sync_init(&s, &cfg, sink_set, sink_release, &k), 0);
    struct f4d_sync_config bad = cfg;
    bad.n_cams = 0;
    assert_int_equal(f4d_sync_init(&s, &bad, sink_set, sink_release, &k), F4D_EINVAL);
    assert_int_equal(f4d_sync_init(&s, &cfg, sink_set, sink_release, &k), 0);

    const uint64_t ms = 1000000;
    /* trigger 1 at 100 ms: both cameras, camera 1's clock is 5 s ahead */
    struct hal_edge e1 = {1, 100 * ms, 0, true};
    f4d_sync_edge(&s, &e1);
    struct hal_buffer a1 = frame(0, 1, 100 * ms + 10, 103 * ms);
    struct hal_buffer b1 = frame(1, 1, 5100 * ms + 20, 104 * ms);
    f4d_sync_frame(&s, &a1);
    f4d_sync_advance(&s, 104 * ms);
    assert_int_equal(k.sets, 0); /* not complete, not yet due */
    f4d_sync_frame(&s, &b1);
    f4d_sync_advance(&s, 104 * ms);
    assert_int_equal(k.sets, 1);
    assert_int_equal(k.last_ok_mask, 3);
    assert_int_equal(s.c.sets_complete, 1);

    /* duplicate of a closed set, then a late frame of an incomplete one */
    struct hal_buffer dup = b1;
    f4d_sync_frame(&s, &dup);
    assert_int_equal(s.c.frames_duplicate, 1);
    struct hal_edge e2 = {2, 133 * ms, 0, true};
    f4d_sync_edge(&s, &e2);
    struct hal_buffer a2 = frame(0, 2, 133 * ms + 30, 136 * ms);
    f4d_sync_frame(&s, &a2);
    f4d_sync_advance(&s, 160 * ms); /* deadline 153 ms passed */
    assert_int_equal(k.sets, 2);
    assert_int_equal(k.marked, 1);
    assert_int_equal(s.c.frames_dropped, 1);
    struct hal_buffer b2 = frame(1, 2, 5133 * ms, 170 * ms);
    f4d_sync_frame(&s, &b2);
    assert_int_equal(s.c.frames_late, 1);
    assert_int_equal(s.c.frames_dropped, 0); /* reclassified */

    /* a frame whose timestamp belongs to another trigger is never grouped */
    struct hal_edge e3 = {3, 166 * ms, 0, true};
    f4d_sync_edge(&s, &e3);
    struct hal_buffer a3 = frame(0, 3, 166 * ms, 169 * ms);
    struct hal_buffer b3 = frame(1, 3, 5166 * ms + 33 * ms, 170 * ms); /* 33 ms off */
    f4d_sync_frame(&s, &a3);
    f4d_sync_frame(&s, &b3);
    assert_int_equal(s.c.frames_out_of_window, 1);
    f4d_sync_flush(&s);
    assert_int_equal(k.sets, 3);
    assert_int_equal(k.last_ok_mask, 1);
    assert_int_equal(s.c.frames_dropped, 0); /* rejected is not dropped */

    /* drop policy, pending bound and clock reset */
    struct sink k2 = {0};
    cfg.policy = HAL_INCOMPLETE_DROP;
    cfg.pending_max = 2;
    assert_int_equal(f4d_sync_init(&s, &cfg, sink_set, sink_release, &k2), 0);
    struct hal_buffer f[4];
    for (int i = 0; i < 4; i++) {
        f[i] = frame(0, (uint64_t)i + 10, (uint64_t)i * 33 * ms, (uint64_t)i * 33 * ms);
        f4d_sync_frame(&s, &f[i]);
    }
    assert_int_equal(s.c.sets_forced, 2);
    assert_int_equal(s.c.sets_dropped, 2);
    assert_int_equal(k2.sets, 0);
    struct hal_buffer r = frame(1, 13, 999 * ms, 100 * ms);
    r.flags = HAL_FRAME_FLAG_CLOCK_RESET;
    f4d_sync_frame(&s, &r);
    assert_int_equal(s.c.clock_resets, 1);
    f4d_sync_advance(&s, 0);
    assert_int_equal(k2.sets, 0); /* 13 is complete but 12 is still open */
    f4d_sync_flush(&s);
    assert_int_equal(k2.sets, 1);
    assert_int_equal(k2.last_seq, 13);
    assert_int_equal(k2.released, 5);
}

/* ---- 10,000+ triggers with every fault on ---- */
struct truth {
    uint64_t sets, mixed, frames;
};
static int check_set(void *u, const struct hal_set *set)
{
    struct truth *t = u;
    t->sets++;
    bool mixed = false;
    for (uint32_t c = 0; c < HAL_RIG_CAMERAS_MAX; c++) {
        const struct hal_buffer *b = set->frames[c];
        if (!b)
            continue;
        uint64_t seq;
        uint32_t cam;
        assert_int_equal(hal_sim_stamp_read(b->data, b->bytes_used, &seq, &cam), 0);
        mixed |= seq != set->seq || cam != c;
        t->frames++;
    }
    t->mixed += mixed;
    return 0;
}

/* A camera whose first frames mislead the offset estimate (e.g. a slow first
 * GigE frame) is relearned after F4D_SYNC_RELEARN_MISSES misses instead of
 * being rejected for ever. */
static void sync_relearns_after_bad_start(void **state)
{
    (void)state;
    struct sink k = {0};
    struct f4d_sync s;
    struct f4d_sync_config cfg = {1, 1000, 20000, HAL_INCOMPLETE_MARK, 4, 4};
    assert_int_equal(f4d_sync_init(&s, &cfg, sink_set, sink_release, &k), 0);
    const uint64_t ms = 1000000;
    struct hal_buffer b[40];
    for (uint64_t seq = 1; seq <= 40; seq++) {
        uint64_t t = seq * 40 * ms;
        struct hal_edge e = {seq, t, 0, true};
        f4d_sync_edge(&s, &e);
        uint64_t lag = seq <= 4 ? 30 * ms : 1 * ms; /* four slow frames, then normal */
        b[seq - 1] = frame(0, seq, t + lag, t + lag);
        f4d_sync_frame(&s, &b[seq - 1]);
        f4d_sync_advance(&s, t + 30 * ms);
    }
    f4d_sync_flush(&s);
    assert_int_equal(s.c.frames_out_of_window, F4D_SYNC_RELEARN_MISSES);
    assert_int_equal(s.c.clock_resets, 1);
    assert_int_equal(s.c.sets_complete, 40 - F4D_SYNC_RELEARN_MISSES);
    assert_int_equal(k.released, 40);
}

static void sync_fault_injection_10k(void **state)
{
    (void)state;
    struct hal_board board;
    struct f4d_err err = {0};
    assert_int_equal(hal_board_load(&board, F4D_BOARD_DIR "/sim-4cam-faulty.json", &err), 0);
    board.sim.realtime = false;
    for (uint32_t i = 0; i < board.n_cams; i++) {
        board.cams[i].width = 32;
        board.cams[i].height = 32;
        board.cams[i].pixfmt = HAL_PIXFMT_MONO8;
    }
    struct hal_rig rig;
    assert_int_equal(hal_rig_open(&rig, &board, &err), 0);
    struct truth t = {0};
    struct f4d_capture_stats st;
    struct f4d_capture_config cfg = {.triggers = 10000};
    int rc = f4d_capture_run(&rig, &cfg, check_set, NULL, &t, NULL, &st, &err);
    if (rc < 0)
        fail_msg("capture: %s", err);
    struct hal_sim_injected inj;
    assert_int_equal(hal_sim_injected_get(hal_rig_session(&rig, "sim"), &inj), 0);
    hal_rig_close(&rig);

    const struct f4d_sync_counters *c = &st.sync;
    printf("[ sync 10k ] pulses %llu edges %llu (missing %llu extra %llu) sets %llu complete %llu "
           "incomplete %llu | frames dropped %llu/%llu late %llu/%llu dup %llu/%llu incomplete "
           "%llu/%llu (counted/injected) disconnects %llu clock resets %llu out_of_window %llu "
           "mixed %llu, %.1f s simulated\n",
           (unsigned long long)inj.pulses_scheduled, (unsigned long long)inj.edges,
           (unsigned long long)inj.triggers_missing, (unsigned long long)inj.triggers_extra,
           (unsigned long long)t.sets, (unsigned long long)c->sets_complete,
           (unsigned long long)c->sets_incomplete, (unsigned long long)c->frames_dropped,
           (unsigned long long)inj.frames_dropped, (unsigned long long)c->frames_late,
           (unsigned long long)inj.frames_late, (unsigned long long)c->frames_duplicate,
           (unsigned long long)inj.frames_duplicate, (unsigned long long)c->frames_incomplete,
           (unsigned long long)inj.frames_incomplete, (unsigned long long)inj.disconnects,
           (unsigned long long)c->clock_resets, (unsigned long long)c->frames_out_of_window,
           (unsigned long long)t.mixed, (double)(st.t_end_ns - st.t_start_ns) * 1e-9);
    assert_int_equal(inj.pulses_scheduled, 10000);
    assert_true(inj.edges >= 10000 - inj.triggers_missing);
    /* every fault really happened */
    assert_true(inj.triggers_missing > 0 && inj.triggers_extra > 0);
    assert_true(inj.frames_late > 0 && inj.frames_duplicate > 0 && inj.frames_incomplete > 0);
    assert_true(inj.frames_dropped > inj.frames_lost_disconnected && inj.disconnects > 0);
    assert_int_equal(inj.underruns, 0);
    /* zero mixed sets, every fault counted exactly as injected */
    assert_int_equal(t.mixed, 0);
    assert_int_equal(c->triggers, inj.edges);
    assert_int_equal(c->sets_complete + c->sets_incomplete, inj.edges);
    assert_int_equal(t.sets, inj.edges); /* policy "mark": every set is passed on */
    assert_int_equal(c->frames_dropped, inj.frames_dropped);
    assert_int_equal(c->frames_late, inj.frames_late);
    assert_int_equal(c->frames_duplicate, inj.frames_duplicate);
    assert_int_equal(c->frames_incomplete, inj.frames_incomplete);
    assert_int_equal(c->frames_out_of_window, 0);
    assert_int_equal(c->frames_stale, 0);
    assert_int_equal(c->frames_ok + c->frames_incomplete + c->frames_late,
                     inj.frames_exposed - (inj.frames_dropped - inj.frames_lost_disconnected));
    assert_int_equal(st.disconnects > 0, 1);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(sync_by_hand),
        cmocka_unit_test(sync_relearns_after_bad_start),
        cmocka_unit_test(sync_fault_injection_10k),
    };
    return cmocka_run_group_tests_name("firmware/capture/sync", tests, NULL, NULL);
}
