/* interp.h - 4D interpolation between two key frames (the non-learned part of
 * Forge4D, forge4d-arch.md §6) and the scene budget (pruning). Library
 * f4d_interp, depends on f4d_splat.
 *
 *     interp *ip;
 *     interp_new(ctx, &rig, &ip, &err);
 *     struct interp_key k0 = {0}, k1 = {0};
 *     interp_key_build(ip, &frame_tm1, &k0);   // t-1, needs motion_fwd (M2[t-1])
 *     interp_key_build(ip, &frame_t,   &k1);   // t,   needs motion_bwd (M1[t])
 *     struct interp_config cfg = interp_config_default();
 *     interp_at(ip, &k0, &k1, 0.5f, &cfg, &out, &stats);   // t' = t - 1 + 0.5
 *
 * Time a is in key intervals: t' = t - 1 + a, a in [0, 1]. Deformation with
 * constant velocity: mu_b = mu[t] + (1 - a) M1[t], mu_f = mu[t-1] + a M2[t-1];
 * other attributes are kept.
 *
 * Dual consistency: a Gaussian of t seen in view i at pixel u (its "origin")
 * is moved by M1[t] to X' and projected into view i; the Gaussian of t-1 at
 * that pixel is its partner and D = |X' - mu[t-1][partner]| (metres). The
 * symmetric test runs for t-1 with M2. D > tau (0.05 m) or no partner: the
 * Gaussian is occluded in the other frame and kept (deformed). Gaussians of t
 * with D <= tau are fused with their partner by the fusion function;
 * Gaussians of t-1 with D <= tau are dropped.
 *
 * Pixel lookup: Forge4D's Gaussians are pixel-aligned, one per input pixel.
 * For any frame, interp_key_build renders the depth of every view (or takes
 * a z-buffer's, interp_set_lookup) and lists,
 * per pixel, the Gaussians whose centre falls in that pixel and is visible
 * there (centre depth within INTERP_VISIBLE_TOL of the rendered depth). A
 * Gaussian's origin is the first view where it is listed. The lookup reads
 * the list of the pixel the moved Gaussian lands on: a pixel-aligned frame has
 * exactly one Gaussian there, as in the paper; a denser frame (the synthetic
 * ground truth) may have several and the one nearest to X' is taken (the
 * lowest index on a tie). Each pixel's list is kept sorted along the view
 * axis, so the search starts where X' sits on it and stops once the distance
 * along the axis alone exceeds the best found or tau (a nearest one farther
 * than tau is no partner either way): the same partner as a full scan.
 * Gaussians that are visible nowhere have no origin and no partner: kept.
 * interp_key_build_aligned skips the render for a frame that IS pixel aligned
 * (the model's output, Gaussian (s * H + y) * W + x from view s, pixel
 * (x, y)): its lookup is the identity, exactly the paper's "read the Gaussian
 * at u'", and it costs no render.
 *
 * Cameras may change from key to key (Forge4D predicts them per time):
 * interp_set_rig swaps them in without allocating, and each key keeps the
 * cameras it was built with. A moved point X' is projected with the cameras
 * of the key whose pixel lists it reads (X' lives at that key's time).
 *
 * Hard cases: a moved point at camera depth <= SPLAT_NEAR (behind the camera)
 * or landing outside the image, or not finite, has no partner (kept, no NaN);
 * a zero quaternion reaching fusion leaves as the identity rotation.
 */
#ifndef F4D_INTERP_H
#define F4D_INTERP_H

#define INTERP_VISIBLE_TOL 0.10f /* metres */

#include "splat.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Attribute vector of one Gaussian as the fusion function sees it:
 * mu (3), colour (3), logit(opacity) (1), log(scale) (3), quaternion (4). */
#define INTERP_ATTRS 14

/* Merges a matched pair (a_t from key t, a_tm1 from key t-1, both already
 * deformed to t') into out. a: the time fraction, D: the consistency distance. */
typedef void (*interp_fuse_fn)(void *user, const float a_t[INTERP_ATTRS], const float a_tm1[INTERP_ATTRS],
                               float a, float D, float out[INTERP_ATTRS]);

/* Averaging: the mean of both vectors, the quaternion as the normalised,
 * sign-aligned sum. What an untrained fusion MLP computes. */
void interp_fuse_average(void *user, const float a_t[INTERP_ATTRS], const float a_tm1[INTERP_ATTRS],
                         float a, float D, float out[INTERP_ATTRS]);

/* Batched fusion: n <= INTERP_FUSE_BATCH pairs in one call, so that a learned
 * F_theta runs as two GEMMs instead of one small MLP per pair. x is [n,
 * INTERP_FUSE_IN], each row a_t (14) | a_tm1 (14) | a | D; out [n, 14] gets
 * what interp_fuse_fn would give for each row. Returns 0, or < 0 to fail
 * interp_at (with F4D_EINVAL and a message naming the fusion). */
#define INTERP_FUSE_IN    (2 * INTERP_ATTRS + 2)
#define INTERP_FUSE_BATCH 1024
typedef int (*interp_fuse_batch_fn)(void *user, const float *x, int n, float *out);

enum interp_mode {
    INTERP_FUSED     = 0, /* Forge4D: occluded kept, matched pairs fused     */
    INTERP_KEEP_BOTH = 1, /* no fusion: every Gaussian of both keys, deformed */
    INTERP_NEAREST   = 2, /* baseline: the nearest key frame, not deformed    */
};

struct interp_config {
    enum interp_mode mode;
    float            tau;       /* metres, 0.05 */
    interp_fuse_fn   fuse;      /* interp_fuse_average by default */
    void            *fuse_user;
    interp_fuse_batch_fn fuse_batch; /* NULL by default; when set, used instead of fuse */
    void            *fuse_batch_user;
};
struct interp_config interp_config_default(void);

struct interp_stats {
    size_t fused, kept_t, kept_tm1, dropped_tm1, no_origin_t, no_origin_tm1;
};

typedef struct interp interp;

/* A workspace for the rig's cameras; ctx (borrowed) gives the threads. */
int  interp_new (fk_ctx *ctx, const struct splat_rig *rig, interp **out, struct f4d_err *err);
void interp_free(interp *ip);

/* How interp_key_build finds the depth each pixel shows (the visibility
 * test's reference): RENDER (default) the rasterizer's expected depth;
 * ZBUFFER the nearest depth among the Gaussians whose centre lands in the
 * pixel or whose core (alpha >= 1/2 of a disc as wide as its largest scale)
 * covers it, with no sort and no compositing: the surface the pixel mostly shows, several times cheaper,
 * and the partners change slightly (f4d-bench pairs --psnr measures the
 * frames against RENDER's). For the keys built from now on. */
enum interp_lookup {
    INTERP_LOOKUP_RENDER  = 0,
    INTERP_LOOKUP_ZBUFFER = 1,
};
int  interp_set_lookup(interp *ip, enum interp_lookup mode, struct f4d_err *err);
/* New cameras for the keys built from now on: same count and image size as
 * the rig of interp_new (F4D_EINVAL otherwise); never allocates. */
int  interp_set_rig(interp *ip, const struct splat_rig *rig, struct f4d_err *err);

/* One key frame with its pixel lookup: per-view maps of the pixel's Gaussian
 * and each Gaussian's origin. Zero-initialise, build, reuse, free. The frame
 * is borrowed and must outlive the key; the lookup (the rendered depth, the
 * lists and their positions) is the frame's as built: rebuild the key after
 * moving its Gaussians. A display builds each key once and keeps it for both
 * of its pairs (as the later key of one, the earlier of the next). */
struct interp_key {
    const struct splat_frame *f;
    int32_t *cell_start;   /* [views * (H * W + 1)] start of each pixel's list */
    int32_t *cell_items;   /* [views * count] Gaussian indices, by pixel        */
    float   *cell_pos;     /* [4][views * count] their positions (x, y, z planes)
                              and f = zaxis . mu in the same order, copied
                              from f at the build: a pixel's list is read from
                              one place, sorted by f (ties by index)          */
    int32_t *origin;       /* [count] view * H * W + pixel, -1 none            */
    size_t   cap_cells, cap_items, cap_origin, cap_pos;
    struct splat_rig rig;  /* the cameras the key was built with              */
    float    zaxis[SPLAT_RIG_MAX][3]; /* unit viewing axis of each camera     */
    float    pos_l1;       /* largest |x| + |y| + |z| listed (rounding bound)   */
    int      aligned;      /* built by interp_key_build_aligned               */
};
int  interp_key_build(interp *ip, const struct splat_frame *f, struct interp_key *k, struct f4d_err *err);
/* The same for a pixel-aligned frame: f->count must be views * H * W of the
 * rig. Allocates only when the key's arrays are smaller than the frame (build
 * once at full size to plan; later builds allocate nothing). */
int  interp_key_build_aligned(interp *ip, const struct splat_frame *f, struct interp_key *k,
                              struct f4d_err *err);
void interp_key_free (struct interp_key *k);

/* The Gaussians at t' = t - 1 + a into out (resized, no motion). prev needs
 * motion_fwd, next needs motion_bwd (except for INTERP_NEAREST). stats may be
 * NULL. */
int  interp_at(interp *ip, const struct interp_key *prev, const struct interp_key *next, float a,
               const struct interp_config *cfg, struct splat_frame *out, struct interp_stats *stats,
               struct f4d_err *err);

/* A key pair's correspondences, for many times between the same two keys:
 * the partners and distances interp_at would find (they depend on the keys,
 * not on a), found once; interp_pair_at then evaluates any a and gives what
 * interp_at gives, bit for bit, without the lookups. Zero-initialise, build,
 * reuse (arrays grow only for more Gaussians than before), free. The keys
 * are borrowed and must outlive the pair. */
struct interp_pair {
    const struct interp_key *prev, *next;
    int32_t *partner_t;    /* [next count] partner in prev, or -1: kept        */
    int32_t *partner_tm1;  /* [prev count] partner in next, or -1: kept        */
    float   *dist_t;       /* [next count] consistency distance D (metres) to
                              the partner; unspecified where there is none    */
    size_t   cap_t, cap_tm1;
    float    tau;          /* the tau it was built with                        */
    struct interp_stats st;/* the a-independent counts                         */
    float   *pos0, *dpos;  /* [3 * n_out] interp_pair_prepare: pos(a) = pos0 + a dpos */
    size_t   n_out, cap_out;
};
int  interp_pair_build(interp *ip, const struct interp_key *prev, const struct interp_key *next,
                       const struct interp_config *cfg, struct interp_pair *pr, struct f4d_err *err);
/* INTERP_FUSED only (build and evaluate with the same cfg; ip: the batched
 * fusion's scratch). */
int  interp_pair_at(interp *ip, const struct interp_pair *pr, float a, const struct interp_config *cfg,
                    struct splat_frame *out, struct interp_stats *stats, struct f4d_err *err);
void interp_pair_free(struct interp_pair *pr);

/* The per-step path (one call per displayed frame): with averaging only the
 * positions depend on a, and linearly (mu_b and mu_f are affine in a, and so
 * is their mean). interp_pair_prepare writes interp_pair_at(a = 0)'s frame
 * into out (count, scale, rotation, opacity, colour: bit for bit, a does not
 * change them) and, into the pair, pos0 and dpos per output Gaussian;
 * interp_pair_step then writes only out->pos = pos0 + a dpos, a flat loop the
 * compiler vectorises, split over ip's threads: it reads 24 and writes 12
 * bytes per Gaussian, allocates nothing, and leaves out's other attributes as
 * prepared (do not change them between steps). Its positions equal
 * interp_pair_at's up to float rounding (the sum is associated differently:
 * within 2e-6 (1 + |pos|) here). Averaging (cfg->fuse ==
 * interp_fuse_average, no fuse_batch) only: F4D_EINVAL otherwise. Same
 * result with any thread count (each element is computed alone). */
int  interp_pair_prepare(interp *ip, struct interp_pair *pr, const struct interp_config *cfg,
                         struct splat_frame *out, struct f4d_err *err);
int  interp_pair_step(interp *ip, const struct interp_pair *pr, float a, struct splat_frame *out,
                      struct f4d_err *err);

/* ---- scene budget ---------------------------------------------------------- */

struct budget_config {
    float min_opacity;     /* prune below (0.02)                                    */
    float min_footprint;   /* pixels (1.0): a Gaussian whose 2-sigma diameter is
                              below this in every camera is merged with its
                              neighbours in a cell of one pixel's size at its
                              depth (it is not dropped: a dense surface of
                              sub-pixel Gaussians would get holes)                 */
    float voxel;           /* metres (0.004): Gaussians sharing a cell of this
                              size are merged (duplicates across views); 0: off  */
};
struct budget_config budget_config_default(void);

struct budget_stats {
    size_t total, pruned_opacity, pruned_outside, subpixel, merged, kept;
};

/* Prunes and merges `in` into `out` (in and out must differ): drops Gaussians
 * below min_opacity and those outside every camera's view, then merges per
 * cell (cells are powers of two times `voxel`, at least one pixel's footprint
 * for sub-pixel Gaussians). A merged Gaussian has the opacity-weighted mean
 * position and colour and the largest opacity; its shape is moment matched:
 * the covariance is the opacity-weighted mean of the members' covariances
 * R diag(s²) Rᵀ plus the weighted spread of their centres, and the merged
 * rotation is that covariance's eigenvector frame (as a quaternion), the
 * scale the square roots of its eigenvalues, so that it covers its members.
 * A cell of one Gaussian keeps it unchanged. Motion: when `in` has either
 * motion array, `out` gets both, each the members' opacity-weighted mean
 * motion (the same weights as the position, so a merged Gaussian moves with
 * its members' centre); an array `in` lacks is zero in `out`. When `in` has
 * no motion, `out`'s motion arrays are freed (NULL). */
int  budget_prune(const struct splat_frame *in, const struct splat_rig *rig, const struct budget_config *cfg,
                  struct splat_frame *out, struct budget_stats *stats, struct f4d_err *err);
/* The same with caller scratch of budget_scratch_bytes(in->count): no
 * allocation when out already has the capacity (a per-frame path plans both
 * once for its largest frame). Too little scratch: F4D_EINVAL. */
size_t budget_scratch_bytes(size_t count);
int  budget_prune_ws(const struct splat_frame *in, const struct splat_rig *rig, const struct budget_config *cfg,
                     void *scratch, size_t scratch_bytes, struct splat_frame *out, struct budget_stats *stats,
                     struct f4d_err *err);
/* The same, also writing origin[k] (room for in->count) = the index in `in`
 * of out Gaussian k's most opaque member: for pixel-aligned input, the pixel
 * it comes from (a stream encoder matches keys through it). */
int  budget_prune_origin_ws(const struct splat_frame *in, const struct splat_rig *rig,
                            const struct budget_config *cfg, void *scratch, size_t scratch_bytes,
                            struct splat_frame *out, uint32_t *origin, struct budget_stats *stats,
                            struct f4d_err *err);

#ifdef __cplusplus
}
#endif
#endif /* F4D_INTERP_H */
