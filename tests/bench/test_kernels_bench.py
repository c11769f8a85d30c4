"""bench kernels --ir (bench/kernels.py: ir_counts): instruction counts of each task from Taichi's optimized IR.

Guards the parser only (which lines count, and as what), on a hand-written excerpt shaped like Taichi 1.7's
output: it says nothing about the kernels themselves."""
from gausstac_maniskill.bench.kernels import ir_counts

IR = """
define void @advance_c1_0_kernel_0_serial(%struct.RuntimeContext* %0) {
  %2 = load float, float* %1, align 4
  ret void
}

define void @advance_c1_0_kernel_1_range_for(%struct.RuntimeContext* %0) {
allocs:
  call void @cpu_parallel_range_for(i8* %0)
  ret void
}

define internal void @function_body(%struct.RuntimeContext* %0, i8* %1, i32 %2) #5 {
  %4 = load <2 x float>, <2 x float>* %3, align 4
  %5 = fmul reassoc ninf nsz <2 x float> %4, %4
  %6 = fadd reassoc ninf nsz float %a, %b
  ; a comment is not an instruction
  %7 = phi i32 [ 0, %allocs ], [ %8, %loop ]
  store <2 x float> %5, <2 x float>* %3, align 4
  br label %loop
}

define internal void @cpu_parallel_range_for_task(i8* %0) {
  %2 = fadd float %a, %b
  ret void
}

define void @prepare_c1_0_kernel_1_range_for(%struct.RuntimeContext* %0) {
  ret void
}
"""


def test_ir_counts_take_each_parallel_task_with_its_loop_body():
    counts = ir_counts(IR)
    assert list(counts) == ["advance_c1_0_kernel_1_range_for"]  # serial tasks and other kernels are left out
    c = counts["advance_c1_0_kernel_1_range_for"]
    # the task's launch call, then its body's load, two float operations (one of two lanes) and the store;
    # the runtime function after it, the label, the comment, phi, br and ret are not counted
    assert c == {"all": 5, "load": 1, "store": 1, "float": 3}
