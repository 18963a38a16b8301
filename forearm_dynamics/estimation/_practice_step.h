/* The practice filter's compiled step (_practice_step.c), a type of the _kalman_step
 * extension: the Kalman filter's compiled parts are one extension, a file per job. */
#ifndef FOREARM_PRACTICE_STEP_H
#define FOREARM_PRACTICE_STEP_H
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>

extern PyTypeObject PracticeType;

#endif
