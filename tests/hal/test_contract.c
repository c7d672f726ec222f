/* test_contract.c: ONE contract suite for every camera/trigger backend that can
 * run here: sim, replay (of a take recorded from sim), and aravis against
 * in-process ArvGvFakeCameras over loopback inside a private network namespace
 * that this test makes itself (skipped when it cannot: not root, no unshare).
 *
 * The contract: state rules (enqueue before configure, dequeue before start),
 * validate -> adjusted -> valid negotiation with invalid input never stored,
 * buffers too small rejected, frames carrying status, both timestamps, frame
 * id and trigger sequence (monotonic), stop handing every queued buffer back
 * ABORTED, trigger edges numbered 1, 2, 3..., and the whole rig delivering
 * synchronized sets through the capture loop with no mixed set. */

#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "f4d_capture.h"
#include "f4d_netns.h"
#include "f4d_test.h"
#include "f4d_take.h"
#include "hal_board.h"
#include "hal_registry.h"
#include "hal_replay.h"
#include "hal_sim.h"

#if HAL_TEST_ARAVIS
#include <arv.h>
#endif

static char tmp_root[256]; /* the replay case's own directory (case setup) */
#if HAL_TEST_ARAVIS
static bool netns_ok;
static char netns_why[160] = "the network namespace was not made";
#endif

struct fixture {
    const char *name;
    struct hal_board board;
    uint64_t triggers;        /* for the set test */
    uint64_t min_complete;    /* complete sets required */
    uint32_t dequeue_timeout_us;
    bool stamped;             /* frames carry the sim ground-truth stamp */
    uint64_t max_spread_ns;   /* bound on device-timestamp spread inside a set, 0 = skip */
};

/* ---- the contract ---- */
static void contract_single_camera(struct fixture *fx, struct hal_rig *rig)
{
    struct hal_camera *cam = &rig->cams[0];
    uint8_t small[16];
    struct hal_buffer tiny = {.data = small, .capacity = sizeof small};
    struct hal_buffer *out;
    assert_int_equal(hal_camera_enqueue(cam, &tiny), F4D_ESTATE);
    assert_int_equal(hal_camera_dequeue(cam, &out, 0), F4D_ESTATE);
    assert_int_equal(hal_camera_start(cam), F4D_ESTATE);

    /* negotiation: nonsense is adjusted to something the device supports */
    struct hal_format f = {HAL_PIXFMT_INVALID, 3, 5, 0, fx->board.trigger.rate_mhz, HAL_TRIGGER_HARDWARE,
                           fx->board.cams[0].exposure_us, 0};
    assert_int_equal(hal_camera_validate(cam, &f), HAL_FORMAT_ADJUSTED);
    assert_true(hal_pixfmt_bytes_per_pixel(f.pixfmt) > 0);
    assert_true(f.width >= 3 && f.height >= 5);
    assert_true(f.image_bytes >= (size_t)f.width * f.height);
    assert_int_equal(hal_camera_validate(cam, &f), HAL_FORMAT_VALID);
    /* a format that does not validate unchanged is refused, not stored */
    struct hal_format bad = f;
    bad.pixfmt = HAL_PIXFMT_INVALID;
    assert_true(hal_camera_configure(cam, &bad) < 0);
    assert_true(strlen(hal_camera_last_error(cam)) > 0);
    assert_int_equal(hal_camera_start(cam), F4D_ESTATE);

    /* the board's format, negotiated */
    const struct hal_camera_config *cc = &fx->board.cams[0];
    struct hal_format g = {cc->pixfmt, cc->width, cc->height, 0, fx->board.trigger.rate_mhz,
                           HAL_TRIGGER_HARDWARE, cc->exposure_us, 0};
    int v = hal_camera_validate(cam, &g);
    assert_true(v == HAL_FORMAT_VALID || v == HAL_FORMAT_ADJUSTED);
    assert_int_equal(hal_camera_validate(cam, &g), HAL_FORMAT_VALID);
    assert_int_equal(hal_camera_configure(cam, &g), F4D_OK);
    assert_int_equal(hal_camera_enqueue(cam, &tiny), F4D_EINVAL);
    assert_int_equal(hal_camera_enqueue(cam, NULL), F4D_EINVAL);
}

static void contract_stream(struct fixture *fx, struct hal_rig *rig)
{
    enum { NBUF = 6, WANT = 12 };
    const uint32_t n = rig->n_cams;
    struct hal_format fmt[HAL_RIG_CAMERAS_MAX];
    struct hal_buffer bufs[HAL_RIG_CAMERAS_MAX][NBUF];
    uint8_t *mem[HAL_RIG_CAMERAS_MAX];
    for (uint32_t i = 0; i < n; i++) {
        const struct hal_camera_config *cc = &fx->board.cams[i];
        struct hal_format f = {cc->pixfmt, cc->width, cc->height, 0, fx->board.trigger.rate_mhz,
                               HAL_TRIGGER_HARDWARE, cc->exposure_us, 0};
        if (hal_camera_validate(&rig->cams[i], &f) == HAL_FORMAT_ADJUSTED)
            assert_int_equal(hal_camera_validate(&rig->cams[i], &f), HAL_FORMAT_VALID);
        assert_int_equal(hal_camera_configure(&rig->cams[i], &f), F4D_OK);
        fmt[i] = f;
        mem[i] = calloc(NBUF, f.image_bytes);
        assert_non_null(mem[i]);
        for (int k = 0; k < NBUF; k++) {
            bufs[i][k] = (struct hal_buffer){.data = mem[i] + (size_t)k * f.image_bytes,
                                             .capacity = f.image_bytes};
            assert_int_equal(hal_camera_enqueue(&rig->cams[i], &bufs[i][k]), F4D_OK);
        }
        assert_int_equal(hal_camera_start(&rig->cams[i]), F4D_OK);
    }
    struct hal_pulse_train train = {fx->board.trigger.rate_mhz, fx->board.trigger.pulse_width_us, WANT + 8};
    assert_int_equal(hal_trigger_arm(&rig->trigger, &train), F4D_OK);
    uint32_t got[HAL_RIG_CAMERAS_MAX] = {0};
    uint64_t last_fid[HAL_RIG_CAMERAS_MAX] = {0}, last_seq[HAL_RIG_CAMERAS_MAX] = {0},
             last_host[HAL_RIG_CAMERAS_MAX] = {0};
    uint64_t edge_seq = 0, edge_ts = 0, edges = 0;
    const uint64_t t0 = hal_clock_now(&rig->clock);
    bool done = false;
    while (!done) {
        struct hal_edge e[8];
        int ne = hal_trigger_read_edges(&rig->trigger, e, 8, 0);
        assert_true(ne >= 0);
        for (int k = 0; k < ne; k++) {
            assert_int_equal(e[k].seq, edge_seq + 1); /* numbered 1, 2, 3... */
            assert_true(e[k].ts_ns >= edge_ts);
            assert_true(e[k].rising);
            edge_seq = e[k].seq;
            edge_ts = e[k].ts_ns;
            edges++;
        }
        done = true;
        for (uint32_t i = 0; i < n; i++) {
            struct hal_buffer *b;
            int rc = hal_camera_dequeue(&rig->cams[i], &b, fx->dequeue_timeout_us);
            if (rc == F4D_OK) {
                assert_true(b >= &bufs[i][0] && b < &bufs[i][NBUF]);
                assert_int_equal(b->camera_index, i);
                assert_int_equal(b->format.image_bytes, fmt[i].image_bytes);
                assert_true(b->status == HAL_FRAME_OK || b->status == HAL_FRAME_MISSING_PACKETS);
                if (b->status == HAL_FRAME_OK)
                    assert_int_equal(b->bytes_used, fmt[i].image_bytes);
                assert_true(b->device_ts_ns > 0 && b->host_ts_ns > 0);
                if (got[i]) {
                    assert_true(b->frame_id > last_fid[i]);
                    assert_true(b->trigger_seq > last_seq[i]);
                    assert_true(b->host_ts_ns >= last_host[i]);
                }
                assert_true(b->trigger_seq >= 1);
                last_fid[i] = b->frame_id;
                last_seq[i] = b->trigger_seq;
                last_host[i] = b->host_ts_ns;
                got[i]++;
                assert_int_equal(hal_camera_enqueue(&rig->cams[i], b), F4D_OK);
            } else {
                assert_int_equal(rc, F4D_ETIMEDOUT);
            }
            done &= got[i] >= WANT;
        }
        /* a hang, not a speed limit: 60 s for what takes 3 s at 5 Hz */
        if (hal_clock_now(&rig->clock) - t0 > 60000000000ull)
            fail_msg("%s: frames did not arrive within 60 s (got %u on camera 0)", fx->name, got[0]);
    }
    assert_true(edges >= WANT);
    hal_trigger_disarm(&rig->trigger);
    for (uint32_t i = 0; i < n; i++) {
        /* stop hands every queued buffer back, ABORTED */
        assert_int_equal(hal_camera_stop(&rig->cams[i]), F4D_OK);
        uint32_t aborted = 0;
        struct hal_buffer *b;
        while (hal_camera_dequeue(&rig->cams[i], &b, 0) == F4D_OK) {
            assert_int_equal(b->status, HAL_FRAME_ABORTED);
            aborted++;
        }
        assert_int_equal(aborted, NBUF);
        assert_int_equal(hal_camera_dequeue(&rig->cams[i], &b, 0), F4D_ESTATE);
        free(mem[i]);
    }
    /* drain edges left from the train */
    struct hal_edge e[64];
    while (hal_trigger_read_edges(&rig->trigger, e, 64, 0) > 0) {
    }
}

struct set_check {
    struct fixture *fx;
    uint64_t sets, complete, mixed, max_spread;
    uint64_t wide; /* complete sets spread wider than fx->max_spread_ns */
};

static int check_set(void *u, const struct hal_set *set)
{
    struct set_check *c = u;
    c->sets++;
    c->complete += set->complete;
    uint64_t lo = UINT64_MAX, hi = 0;
    for (uint32_t i = 0; i < c->fx->board.n_cams; i++) {
        const struct hal_buffer *b = set->frames[i];
        if (!b)
            continue;
        bool mixed = b->trigger_seq != set->seq;
        uint64_t seq;
        uint32_t cam;
        if (c->fx->stamped) {
            assert_int_equal(hal_sim_stamp_read(b->data, b->bytes_used, &seq, &cam), 0);
            mixed |= seq != set->seq || cam != i;
        }
        c->mixed += mixed;
        lo = b->device_ts_ns < lo ? b->device_ts_ns : lo;
        hi = b->device_ts_ns > hi ? b->device_ts_ns : hi;
    }
    if (set->complete && hi - lo > c->max_spread)
        c->max_spread = hi - lo;
    if (set->complete && c->fx->max_spread_ns && hi - lo > c->fx->max_spread_ns)
        c->wide++;
    return 0;
}

static void contract_sets(struct fixture *fx, struct hal_rig *rig)
{
    struct set_check chk = {fx, 0, 0, 0, 0, 0};
    struct f4d_capture_config cfg = {.triggers = fx->triggers};
    struct f4d_capture_stats st;
    struct f4d_err err = {0};
    int rc = f4d_capture_run(rig, &cfg, check_set, NULL, &chk, NULL, &st, &err);
    if (rc < 0)
        fail_msg("%s: capture: %s", fx->name, err);
    printf("[ %s ] %u cameras: %llu sets, %llu complete, %llu mixed; frames dropped %llu, "
           "incomplete %llu, out of window %llu; max device-ts spread in a set %.2f ms (%llu wide)\n",
           fx->name, (unsigned)rig->n_cams, (unsigned long long)chk.sets,
           (unsigned long long)chk.complete, (unsigned long long)chk.mixed,
           (unsigned long long)st.sync.frames_dropped, (unsigned long long)st.sync.frames_incomplete,
           (unsigned long long)st.sync.frames_out_of_window, (double)chk.max_spread * 1e-6,
           (unsigned long long)chk.wide);
    assert_int_equal(chk.mixed, 0);
    assert_true(chk.complete >= fx->min_complete);
    /* Frames paired with a neighbouring trigger would put nearly every set a
     * whole period apart; a few sets wider than half a period are a fake
     * camera's thread descheduled on a loaded machine (its device timestamp
     * is taken when it fills the frame), so at most 5 % may be. */
    if (fx->max_spread_ns && chk.wide * 20 > chk.complete)
        fail_msg("%s: %llu of %llu complete sets spread over %.1f ms", fx->name,
                 (unsigned long long)chk.wide, (unsigned long long)chk.complete,
                 (double)fx->max_spread_ns * 1e-6);
}

static void run_contract(struct fixture *fx)
{
    struct hal_rig rig;
    struct f4d_err err = {0};
    int rc = hal_rig_open(&rig, &fx->board, &err);
    if (rc < 0)
        fail_msg("%s: rig: %s", fx->name, err);
    contract_single_camera(fx, &rig);
    contract_stream(fx, &rig);
    contract_sets(fx, &rig);
    hal_rig_close(&rig);
}

/* ---- backends ---- */
static void sim_fixture(struct fixture *fx)
{
    struct f4d_err err = {0};
    memset(fx, 0, sizeof *fx);
    fx->name = "sim";
    assert_int_equal(hal_board_load(&fx->board, F4D_BOARD_DIR "/sim-4cam.json", &err), 0);
    fx->board.sim.realtime = false;
    for (uint32_t i = 0; i < fx->board.n_cams; i++) {
        fx->board.cams[i].width = 64;
        fx->board.cams[i].height = 48;
    }
    fx->triggers = 200;
    fx->min_complete = 200;
    fx->dequeue_timeout_us = 5000;
    fx->stamped = true;
}

static void contract_sim(void **state)
{
    (void)state;
    struct fixture fx;
    sim_fixture(&fx);
    run_contract(&fx);
}

struct recording {
    struct fixture *fx;
    struct f4d_take_writer *w;
};

static int rec_ready(void *user, const struct f4d_capture_stats *st)
{
    struct recording *r = user;
    struct f4d_take_info info = {.n_cams = r->fx->board.n_cams, .rate_mhz = r->fx->board.trigger.rate_mhz};
    for (uint32_t i = 0; i < info.n_cams; i++)
        info.formats[i] = st->formats[i];
    char dir[300];
    struct f4d_err err = {0};
    snprintf(dir, sizeof dir, "%s/take", tmp_root);
    return f4d_take_create(&r->w, dir, &info, NULL, 100, &err);
}

static int rec_set(void *user, const struct hal_set *set)
{
    return f4d_take_append(((struct recording *)user)->w, set);
}

static void contract_replay(void **state)
{
    (void)state;
    /* record 260 sets from the sim, then replay them as a rig */
    struct fixture src;
    sim_fixture(&src);
    struct hal_rig rig;
    struct f4d_err err = {0};
    assert_int_equal(hal_rig_open(&rig, &src.board, &err), 0);
    struct recording rec = {&src, NULL};
    struct f4d_capture_config cfg = {.triggers = 260, .on_ready = rec_ready};
    struct f4d_capture_stats st;
    assert_int_equal(f4d_capture_run(&rig, &cfg, rec_set, NULL, &rec, NULL, &st, &err), 0);
    assert_int_equal(f4d_take_close(rec.w, &err), 0);
    hal_rig_close(&rig);

    struct fixture fx;
    memset(&fx, 0, sizeof fx);
    fx.name = "replay";
    char dir[300];
    snprintf(dir, sizeof dir, "%s/take", tmp_root);
    assert_int_equal(hal_replay_board(&fx.board, dir, false, &err), 0);
    fx.triggers = 0; /* the take decides */
    fx.min_complete = 200; /* 260 recorded, 20 consumed by the stream test */
    fx.dequeue_timeout_us = 5000;
    fx.stamped = true;
    run_contract(&fx);
}

#if HAL_TEST_ARAVIS
static void contract_aravis(void **state)
{
    (void)state;
    if (!netns_ok)
        f4d_skip("contract_aravis: %s (needs root, or unprivileged user namespaces, and ip from iproute2)",
                 netns_why);
    enum { NCAM = 2 };
    ArvGvFakeCamera *fake[NCAM];
    for (int i = 0; i < NCAM; i++) {
        char ip[32], serial[16];
        snprintf(ip, sizeof ip, "127.0.0.%d", i + 2);
        snprintf(serial, sizeof serial, "F4D%02d", i);
        fake[i] = arv_gv_fake_camera_new_full(ip, serial, NULL);
        assert_non_null(fake[i]);
        /* software triggers are served on the next tick: make ticks 1 ms */
        arv_fake_camera_set_trigger_frequency(arv_gv_fake_camera_get_fake_camera(fake[i]), 1000.0);
    }
    struct fixture fx;
    memset(&fx, 0, sizeof fx);
    fx.name = "aravis";
    hal_board_defaults(&fx.board);
    snprintf(fx.board.name, sizeof fx.board.name, "fake-gige-%dcam", NCAM);
    fx.board.n_cams = NCAM;
    for (int i = 0; i < NCAM; i++) {
        struct hal_camera_config *c = &fx.board.cams[i];
        snprintf(c->backend, sizeof c->backend, "aravis");
        snprintf(c->address, sizeof c->address, "127.0.0.%d", i + 2);
        c->width = 128;
        c->height = 96;
        c->pixfmt = HAL_PIXFMT_MONO8;
        c->packet_size = 8192;
        c->socket_buffer = 4000000;
        c->exposure_us = 1000;
    }
    snprintf(fx.board.trigger.backend, sizeof fx.board.trigger.backend, "aravis");
    /* A fake camera stamps a frame when its thread wakes after the trigger:
     * on a loaded 2-core machine (load 13) that was up to 56 ms late, which
     * a 40 ms period with a 15 ms window turned into a third of the sets
     * incomplete. 5 Hz: a 200 ms period, a 90 ms window (just under half a
     * period: a frame is still told from its neighbours' triggers) and a
     * 500 ms latency bound leave room for such delays. */
    fx.board.trigger.rate_mhz = 5000;
    fx.board.sync.window_us = 90000;
    fx.board.sync.max_latency_us = 500000;
    fx.board.sync.pending_max = 8;
    fx.board.sync.incomplete = HAL_INCOMPLETE_MARK;
    fx.triggers = 100;
    fx.min_complete = 60;
    fx.dequeue_timeout_us = 2000;
    fx.max_spread_ns = 100000000; /* half a period: frames of one trigger, not neighbours */
    run_contract(&fx);
    for (int i = 0; i < NCAM; i++)
        g_object_unref(fake[i]);
}

/* Private network namespace with loopback aliases: camera traffic never leaves it. */
static void make_netns(void)
{
    netns_ok = f4d_test_netns(4, netns_why, sizeof netns_why) == 0;
}

#endif /* HAL_TEST_ARAVIS */

/* The replay case records its own take in a directory of its own: no case
 * reads what another wrote, so any order and any subset runs. */
static int setup_tmp(void **state)
{
    (void)state;
    return f4d_test_mkdtemp(tmp_root, sizeof tmp_root, "test_contract");
}

static int teardown_tmp(void **state)
{
    (void)state;
    int rc = f4d_test_rmtree(tmp_root);
    tmp_root[0] = 0;
    return rc;
}

int main(int argc, char **argv)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(contract_sim),
        cmocka_unit_test_setup_teardown(contract_replay, setup_tmp, teardown_tmp),
#if HAL_TEST_ARAVIS
        cmocka_unit_test(contract_aravis),
#endif
    };
    argc = f4d_test_parse(argc, argv);
    if (argc < 0)
        return 2;
#if HAL_TEST_ARAVIS
    /* before any thread exists: a namespace belongs to the thread that makes it */
    if (f4d_test_selected("contract_aravis"))
        make_netns();
#endif
    return F4D_TEST_MAIN(argc, argv, "hal/contract", tests, NULL, NULL);
}
