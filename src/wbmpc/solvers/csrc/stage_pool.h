/* A small pool of worker threads that runs the tasks 0 .. n-1 of one job, the calling thread taking part.
 * Tasks are handed out through an atomic counter, the caller's from the front, the workers' from the back; each
 * task writes only its own outputs, so the results do not depend on which thread ran which task (the per-stage
 * evaluations of fatrop_shim.c). */
#ifndef WBMPC_STAGE_POOL_H
#define WBMPC_STAGE_POOL_H

#ifdef __cplusplus
extern "C" {
#endif

/* task `task` of a job; `worker` 0 is the calling thread, 1 .. n_workers the pool's threads */
typedef void (*wb_task_fn)(void* job, int task, int worker);

typedef struct wb_pool wb_pool;

/* a pool of n_workers threads besides the caller (0: every job runs in the caller); NULL if out of memory
   or the threads cannot be started */
wb_pool* wb_pool_new(int n_workers);
void wb_pool_free(wb_pool* pool);
int wb_pool_workers(const wb_pool* pool);
/* runs fn(job, i, worker) for i = 0 .. n_tasks - 1 and returns when all have finished */
void wb_pool_run(wb_pool* pool, int n_tasks, wb_task_fn fn, void* job);

#ifdef __cplusplus
}
#endif
#endif
