// hal_libcamera_shim.cpp: the extern "C" shim over libcamera 0.0.3 (see
// hal_libcamera_shim.h). The only C++ in the tree; nothing C++ crosses the
// header: no exceptions (libcamera does not throw; std::bad_alloc at
// configure is caught), opaque handles, F4D_* status codes.
#include "hal_libcamera_shim.h"

#include <libcamera/camera.h>
#include <libcamera/camera_manager.h>
#include <libcamera/control_ids.h>
#include <libcamera/framebuffer.h>
#include <libcamera/framebuffer_allocator.h>
#include <libcamera/request.h>
#include <libcamera/stream.h>

#include <sys/mman.h>

#include <chrono>
#include <condition_variable>
#include <cerrno>
#include <cstdarg>
#include <cstdio>
#include <cstring>
#include <memory>
#include <mutex>
#include <new>
#include <string>
#include <vector>

using namespace libcamera;

namespace {

std::mutex g_lock; // guards g_mgr and g_refs
std::unique_ptr<CameraManager> g_mgr;
uint32_t g_refs;

__attribute__((format(printf, 3, 4))) int fail(struct f4d_err *err, int rc, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    f4d_vfail(err, rc, fmt, ap);
    va_end(ap);
    return rc;
}

void describe_locked(char *buf, size_t cap)
{
    if (!cap)
        return;
    buf[0] = 0;
    std::vector<std::shared_ptr<Camera>> cams;
    if (g_mgr)
        cams = g_mgr->cameras();
    if (cams.empty()) {
        snprintf(buf, cap, "no cameras");
        return;
    }
    size_t used = (size_t)snprintf(buf, cap, "cameras: ");
    for (size_t i = 0; i < cams.size() && used < cap; i++)
        used += (size_t)snprintf(buf + used, cap - used, "%s\"%s\"", i ? ", " : "", cams[i]->id().c_str());
}

struct Mapping {
    void *base = MAP_FAILED;
    size_t len = 0;
    const uint8_t *data = nullptr;
};

} // namespace

struct hlc_camera {
    std::shared_ptr<Camera> cam;
    std::unique_ptr<CameraConfiguration> config;
    std::unique_ptr<FrameBufferAllocator> alloc;
    Stream *stream = nullptr;
    std::vector<std::unique_ptr<Request>> requests; // slot -> request (cookie = slot)
    std::vector<Mapping> maps;                      // slot -> plane 0 mapping
    bool configured = false, started = false;

    // completed requests, written by libcamera's thread
    std::mutex lock;
    std::condition_variable cv;
    std::vector<hlc_completion> ring; // sized at configure: one entry per request
    size_t head = 0, count = 0;
    bool disconnected = false;

    void on_request(Request *r)
    {
        hlc_completion d;
        std::memset(&d, 0, sizeof d);
        d.slot = (uint32_t)r->cookie();
        d.cancelled = r->status() == Request::RequestCancelled;
        FrameBuffer *fb = stream ? r->findBuffer(stream) : nullptr;
        if (fb) {
            const FrameMetadata &md = fb->metadata();
            d.ok = !d.cancelled && md.status == FrameMetadata::FrameSuccess;
            d.sequence = md.sequence;
            d.sensor_ts_ns = md.timestamp;
            if (!md.planes().empty())
                d.bytes_used = md.planes()[0].bytesused;
        }
        std::optional<int64_t> ts = r->metadata().get(controls::SensorTimestamp);
        if (ts && *ts > 0)
            d.sensor_ts_ns = (uint64_t)*ts;
        std::lock_guard<std::mutex> g(lock);
        if (count < ring.size()) { // a request completes once per queue: never full
            ring[(head + count) % ring.size()] = d;
            count++;
        }
        cv.notify_one();
    }

    void on_disconnect()
    {
        std::lock_guard<std::mutex> g(lock);
        disconnected = true;
        cv.notify_all();
    }

    void free_buffers()
    {
        for (Mapping &m : maps)
            if (m.base != MAP_FAILED)
                munmap(m.base, m.len);
        maps.clear();
        requests.clear();
        if (alloc && stream)
            alloc->free(stream);
        alloc.reset();
        std::lock_guard<std::mutex> g(lock);
        ring.clear();
        head = count = 0;
    }
};

extern "C" {

int hlc_manager_start(struct f4d_err *err)
{
    std::lock_guard<std::mutex> g(g_lock);
    if (g_refs > 0) {
        g_refs++;
        return F4D_OK;
    }
    try {
        g_mgr = std::make_unique<CameraManager>();
    } catch (const std::bad_alloc &) {
        return fail(err, F4D_ENOMEM, "libcamera: out of memory");
    }
    int r = g_mgr->start();
    if (r < 0) {
        g_mgr.reset();
        return fail(err, F4D_EIO, "libcamera: CameraManager::start failed: %s", std::strerror(-r));
    }
    g_refs = 1;
    return F4D_OK;
}

int hlc_manager_stop(void)
{
    std::lock_guard<std::mutex> g(g_lock);
    if (g_refs == 0)
        return F4D_ESTATE;
    if (--g_refs == 0) {
        g_mgr->stop();
        g_mgr.reset();
    }
    return F4D_OK;
}

uint32_t hlc_manager_refs(void)
{
    std::lock_guard<std::mutex> g(g_lock);
    return g_refs;
}

int hlc_manager_count(void)
{
    std::lock_guard<std::mutex> g(g_lock);
    if (!g_mgr)
        return F4D_ESTATE;
    return (int)g_mgr->cameras().size();
}

int hlc_manager_camera_id(uint32_t i, char *buf, size_t cap)
{
    std::lock_guard<std::mutex> g(g_lock);
    if (!g_mgr)
        return F4D_ESTATE;
    std::vector<std::shared_ptr<Camera>> cams = g_mgr->cameras();
    if (i >= cams.size())
        return F4D_EINVAL;
    snprintf(buf, cap, "%s", cams[i]->id().c_str());
    return F4D_OK;
}

void hlc_manager_describe(char *buf, size_t cap)
{
    std::lock_guard<std::mutex> g(g_lock);
    describe_locked(buf, cap);
}

int hlc_camera_acquire(const char *id, struct hlc_camera **out, struct f4d_err *err)
{
    *out = nullptr;
    std::lock_guard<std::mutex> g(g_lock);
    if (!g_mgr)
        return fail(err, F4D_ESTATE, "libcamera: camera manager not started");
    std::shared_ptr<Camera> cam = g_mgr->get(id ? id : "");
    if (!cam) {
        char avail[192];
        describe_locked(avail, sizeof avail);
        return fail(err, F4D_ENODEV, "libcamera: no camera with id \"%s\" (libcamera sees %s)",
                    id ? id : "", avail);
    }
    int r = cam->acquire();
    if (r < 0)
        return fail(err, r == -EBUSY ? F4D_EBUSY : F4D_EIO, "libcamera: cannot acquire \"%s\": %s",
                    id, std::strerror(-r));
    hlc_camera *c = new (std::nothrow) hlc_camera;
    if (!c) {
        cam->release();
        return fail(err, F4D_ENOMEM, "libcamera: out of memory");
    }
    c->cam = cam;
    cam->requestCompleted.connect(c, &hlc_camera::on_request);
    cam->disconnected.connect(c, &hlc_camera::on_disconnect);
    *out = c;
    return F4D_OK;
}

void hlc_camera_release(struct hlc_camera *c)
{
    if (!c)
        return;
    hlc_camera_stop(c);
    c->cam->requestCompleted.disconnect(c);
    c->cam->disconnected.disconnect(c);
    c->free_buffers();
    c->cam->release();
    delete c;
}

static int to_config(struct hlc_camera *c, const struct hlc_format *f, struct f4d_err *err)
{
    if (!c->config) {
        c->config = c->cam->generateConfiguration({StreamRole::VideoRecording});
        if (!c->config || c->config->size() == 0)
            return fail(err, F4D_ENOTSUP, "libcamera: \"%s\" offers no video stream",
                        c->cam->id().c_str());
    }
    StreamConfiguration &sc = c->config->at(0);
    sc.pixelFormat = PixelFormat(f->fourcc);
    sc.size = Size(f->width, f->height);
    return F4D_OK;
}

int hlc_camera_validate(struct hlc_camera *c, struct hlc_format *f, struct f4d_err *err)
{
    if (c->started)
        return fail(err, F4D_ESTATE, "validate while started");
    int rc = to_config(c, f, err);
    if (rc < 0)
        return rc;
    CameraConfiguration::Status st = c->config->validate();
    if (st == CameraConfiguration::Invalid)
        return fail(err, F4D_EINVAL, "libcamera: configuration invalid");
    const StreamConfiguration &sc = c->config->at(0);
    struct hlc_format in = *f;
    f->fourcc = sc.pixelFormat.fourcc();
    f->width = sc.size.width;
    f->height = sc.size.height;
    f->stride = sc.stride;
    f->frame_size = sc.frameSize;
    bool same = in.fourcc == f->fourcc && in.width == f->width && in.height == f->height;
    return same ? 0 : 1;
}

int hlc_camera_configure(struct hlc_camera *c, struct hlc_format *f, uint32_t n_buffers, struct f4d_err *err)
{
    if (c->started)
        return fail(err, F4D_ESTATE, "configure while started");
    c->free_buffers();
    c->configured = false;
    int rc = hlc_camera_validate(c, f, err);
    if (rc < 0)
        return rc;
    if (rc > 0)
        return fail(err, F4D_EINVAL, "format does not validate unchanged");
    StreamConfiguration &sc = c->config->at(0);
    if (n_buffers)
        sc.bufferCount = n_buffers;
    int r = c->cam->configure(c->config.get());
    if (r < 0)
        return fail(err, F4D_EIO, "libcamera: Camera::configure: %s", std::strerror(-r));
    c->stream = sc.stream();
    try {
        c->alloc = std::make_unique<FrameBufferAllocator>(c->cam);
        r = c->alloc->allocate(c->stream);
        if (r <= 0)
            return fail(err, F4D_ENOMEM, "libcamera: FrameBufferAllocator::allocate: %s",
                        std::strerror(r < 0 ? -r : ENOMEM));
        const std::vector<std::unique_ptr<FrameBuffer>> &bufs = c->alloc->buffers(c->stream);
        size_t n = bufs.size();
        c->maps.resize(n);
        {
            std::lock_guard<std::mutex> g(c->lock);
            c->ring.resize(n);
        }
        for (size_t i = 0; i < n; i++) {
            const FrameBuffer::Plane &p = bufs[i]->planes()[0];
            Mapping &m = c->maps[i];
            m.len = (size_t)p.offset + p.length;
            m.base = mmap(nullptr, m.len, PROT_READ, MAP_SHARED, p.fd.get(), 0);
            if (m.base == MAP_FAILED) {
                int e = errno;
                c->free_buffers();
                return fail(err, F4D_EIO, "libcamera: mmap of a frame buffer: %s", std::strerror(e));
            }
            m.data = (const uint8_t *)m.base + p.offset;
            std::unique_ptr<Request> req = c->cam->createRequest(i);
            if (!req || req->addBuffer(c->stream, bufs[i].get()) < 0) {
                c->free_buffers();
                return fail(err, F4D_EIO, "libcamera: cannot create request %zu", i);
            }
            c->requests.push_back(std::move(req));
        }
    } catch (const std::bad_alloc &) {
        c->free_buffers();
        return fail(err, F4D_ENOMEM, "libcamera: out of memory");
    }
    c->configured = true;
    return (int)c->requests.size();
}

const uint8_t *hlc_camera_slot_data(struct hlc_camera *c, uint32_t slot)
{
    return slot < c->maps.size() ? c->maps[slot].data : nullptr;
}

int hlc_camera_start(struct hlc_camera *c, struct f4d_err *err)
{
    if (!c->configured)
        return fail(err, F4D_ESTATE, "start before configure");
    if (c->started)
        return F4D_OK;
    int r = c->cam->start();
    if (r < 0)
        return fail(err, r == -ENODEV ? F4D_ENODEV : F4D_EIO, "libcamera: Camera::start: %s",
                    std::strerror(-r));
    c->started = true;
    return F4D_OK;
}

int hlc_camera_stop(struct hlc_camera *c)
{
    if (!c->started)
        return F4D_OK;
    c->cam->stop(); // completes every request in flight as cancelled
    c->started = false;
    return F4D_OK;
}

int hlc_camera_queue(struct hlc_camera *c, uint32_t slot, struct f4d_err *err)
{
    if (!c->started)
        return fail(err, F4D_ESTATE, "queue while stopped");
    if (slot >= c->requests.size())
        return fail(err, F4D_EINVAL, "no request %u", (unsigned)slot);
    Request *r = c->requests[slot].get();
    r->reuse(Request::ReuseBuffers);
    int rc = c->cam->queueRequest(r);
    if (rc < 0)
        return fail(err, rc == -ENODEV ? F4D_ENODEV : F4D_EIO, "libcamera: queueRequest: %s",
                    std::strerror(-rc));
    return F4D_OK;
}

int hlc_camera_wait(struct hlc_camera *c, struct hlc_completion *out, uint32_t timeout_us)
{
    std::unique_lock<std::mutex> g(c->lock);
    c->cv.wait_for(g, std::chrono::microseconds(timeout_us), [c] { return c->count > 0 || c->disconnected; });
    if (c->count > 0) {
        *out = c->ring[c->head];
        c->head = (c->head + 1) % c->ring.size();
        c->count--;
        return F4D_OK;
    }
    return c->disconnected ? F4D_ENODEV : F4D_ETIMEDOUT;
}

} // extern "C"
