/* What the files of the _kalman_step extension share: the Kalman filter's compiled parts are
 * one extension, a file per job (_kalman_step.c: the filter's step and its groups' gains, the
 * module; _practice_step.c: the practice filter's step, the Practice type it registers). */
#ifndef FOREARM_KALMAN_STEP_H
#define FOREARM_KALMAN_STEP_H
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>
#include <string.h>

#include "_buffers.h" /* get_vector, bound_call */

extern PyTypeObject PracticeType;

#endif
