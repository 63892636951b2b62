/* Worker threads for the per-stage evaluations (stage_pool.h).
 *
 * A job is published by bumping `generation`; idle workers spin briefly on it (the next job of a Fatrop
 * iteration follows within a fraction of a millisecond) and then sleep on a condition variable, so an idle
 * pool costs no CPU. The caller takes tasks itself and then waits only for tasks already taken. */
#include "stage_pool.h"

#include <pthread.h>
#include <sched.h>
#include <stdatomic.h>
#include <stdlib.h>

#if defined(__x86_64__) || defined(__i386__)
#include <immintrin.h>
#define WB_RELAX() _mm_pause()
#else
#define WB_RELAX() ((void) 0)
#endif

#define WB_SPIN_WORKER 2000 /* relax instructions before a worker sleeps (~20-50 us: less than a section takes) */
#define WB_SPIN_CALLER 2000  /* ... before the caller yields its core while waiting for a task in flight */

struct wb_pool {
  int n_workers;
  pthread_t* threads;
  pthread_mutex_t lock;
  pthread_cond_t wake;
  int sleepers; /* under lock */
  atomic_uint generation;
  atomic_int stop;
  /* the current job, written by the caller while no task is left or running */
  wb_task_fn fn;
  void* job;
  /* (job number << 32) | (front << 16) | back: the tasks front .. back - 1 are not taken yet. The caller takes
     them from the front, the workers from the back, each by a compare-and-swap on the whole word, so a worker late
     from one job can never take a task of the next one under the old counts. From the two ends, each core keeps
     to one end of the horizon, so it runs (and fetches the machine code of) fewer stage kinds per job: g1's
     first and torque stages on the caller's core, the plain and terminal ones on the worker's. */
  _Atomic unsigned long long ticket;
  atomic_int done;
};

typedef struct {
  wb_pool* pool;
  int worker;
} wb_worker_arg;

#define WB_FRONT(t) ((int) (((t) >> 16) & 0xffffULL))
#define WB_BACK(t) ((int) ((t) & 0xffffULL))

/* take and run tasks until none is left (the caller from the front, workers from the back); a task's job fields
   are read after taking it (they cannot change before it is counted done) */
static void wb_take_tasks(wb_pool* p, int worker) {
  unsigned long long t = atomic_load_explicit(&p->ticket, memory_order_acquire);
  while (WB_FRONT(t) < WB_BACK(t)) {
    const unsigned long long next = worker == 0 ? t + (1ULL << 16) : t - 1;
    if (atomic_compare_exchange_weak_explicit(&p->ticket, &t, next, memory_order_acq_rel, memory_order_acquire)) {
      p->fn(p->job, worker == 0 ? WB_FRONT(t) : WB_BACK(t) - 1, worker);
      atomic_fetch_add_explicit(&p->done, 1, memory_order_release);
      t = atomic_load_explicit(&p->ticket, memory_order_acquire);
    }
  }
}

static unsigned wb_wait_generation(wb_pool* p, unsigned seen) {
  unsigned g;
  int spin;
  for (spin = 0; spin < WB_SPIN_WORKER; ++spin) {
    g = atomic_load_explicit(&p->generation, memory_order_acquire);
    if (g != seen || atomic_load_explicit(&p->stop, memory_order_relaxed)) return g;
    WB_RELAX();
  }
  pthread_mutex_lock(&p->lock);
  p->sleepers++;
  while ((g = atomic_load_explicit(&p->generation, memory_order_acquire)) == seen &&
         !atomic_load_explicit(&p->stop, memory_order_relaxed))
    pthread_cond_wait(&p->wake, &p->lock);
  p->sleepers--;
  pthread_mutex_unlock(&p->lock);
  return g;
}

static void* wb_worker_main(void* arg) {
  wb_worker_arg a = *(wb_worker_arg*) arg;
  wb_pool* p = a.pool;
  unsigned seen = 0;
  free(arg);
  for (;;) {
    seen = wb_wait_generation(p, seen);
    if (atomic_load_explicit(&p->stop, memory_order_relaxed)) break;
    wb_take_tasks(p, a.worker);
  }
  return 0;
}

static void wb_wake_all(wb_pool* p) {
  pthread_mutex_lock(&p->lock);
  if (p->sleepers > 0) pthread_cond_broadcast(&p->wake);
  pthread_mutex_unlock(&p->lock);
}

wb_pool* wb_pool_new(int n_workers) {
  wb_pool* p = (wb_pool*) calloc(1, sizeof(wb_pool));
  int i;
  if (!p) return 0;
  p->threads = (pthread_t*) calloc(n_workers > 0 ? n_workers : 1, sizeof(pthread_t));
  if (!p->threads) { free(p); return 0; }
  pthread_mutex_init(&p->lock, 0);
  pthread_cond_init(&p->wake, 0);
  atomic_init(&p->generation, 0);
  atomic_init(&p->stop, 0);
  atomic_init(&p->ticket, 0ULL);
  atomic_init(&p->done, 0);
  for (i = 0; i < n_workers; ++i) {
    wb_worker_arg* arg = (wb_worker_arg*) malloc(sizeof(wb_worker_arg));
    if (!arg) break;
    arg->pool = p;
    arg->worker = i + 1;
    if (pthread_create(&p->threads[i], 0, wb_worker_main, arg) != 0) { free(arg); break; }
    p->n_workers = i + 1;
  }
  if (p->n_workers < n_workers) { wb_pool_free(p); return 0; }
  return p;
}

void wb_pool_free(wb_pool* p) {
  int i;
  if (!p) return;
  atomic_store_explicit(&p->stop, 1, memory_order_relaxed);
  atomic_fetch_add_explicit(&p->generation, 1, memory_order_release);
  pthread_mutex_lock(&p->lock);
  pthread_cond_broadcast(&p->wake);
  pthread_mutex_unlock(&p->lock);
  for (i = 0; i < p->n_workers; ++i) pthread_join(p->threads[i], 0);
  pthread_cond_destroy(&p->wake);
  pthread_mutex_destroy(&p->lock);
  free(p->threads);
  free(p);
}

int wb_pool_workers(const wb_pool* p) { return p ? p->n_workers : 0; }

void wb_pool_run(wb_pool* p, int n_tasks, wb_task_fn fn, void* job) {
  int i, spin = 0;
  unsigned g;
  if (!p || p->n_workers == 0 || n_tasks < 2 || n_tasks > 0xffff) {
    for (i = 0; i < n_tasks; ++i) fn(job, i, 0);
    return;
  }
  p->fn = fn;
  p->job = job;
  atomic_store_explicit(&p->done, 0, memory_order_relaxed);
  g = atomic_load_explicit(&p->generation, memory_order_relaxed) + 1;
  /* front 0, back n_tasks */
  atomic_store_explicit(&p->ticket, ((unsigned long long) g << 32) | (unsigned) n_tasks, memory_order_release);
  atomic_store_explicit(&p->generation, g, memory_order_release);
  wb_wake_all(p);
  wb_take_tasks(p, 0);
  while (atomic_load_explicit(&p->done, memory_order_acquire) < n_tasks) {
    if (++spin < WB_SPIN_CALLER) WB_RELAX();
    else sched_yield();
  }
}
